"""The fast paths of reading large files give the same answers as before: the content hash of
a frame, numbers parsed once per distinct text, blank-line detection and per-test grouping."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from features.readings import read_readings
from features.readings.errors import InputError
from features.readings.validation import to_float, to_int
from pipeline.results import data_hash

TARGETS = (0.0, 50.0, 100.0)


def table(tests: int = 2, cycles: int = 3) -> pd.DataFrame:
    """``tests`` small canonical tests: 3 targets x 2 directions x ``cycles`` cycles."""
    rows = []
    for t in range(1, tests + 1):
        for cycle in range(1, cycles + 1):
            for direction, offset in (("+", -2.0), ("-", 2.0)):
                for target in TARGETS:
                    rows.append({"machine_id": "M1", "axis": "X", "test_id": f"T{t}",
                                 "method": "linear", "target": target, "direction": direction,
                                 "cycle": cycle,
                                 "deviation_um": 0.01 * target + offset + 0.1 * cycle + t,
                                 "feed_mm_min": 500.0})
    return pd.DataFrame(rows)


def write(tmp_path: Path, frame: pd.DataFrame, name: str = "readings.csv") -> Path:
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


# --------------------------------------------------------------------------- data_hash


def test_data_hash_equal_content_gives_equal_hash(tmp_path):
    frame = read_readings(write(tmp_path, table()))
    again = read_readings(write(tmp_path, table(), "again.csv"))
    assert len(data_hash(frame)) == 64
    assert data_hash(frame) == data_hash(again) == data_hash(frame.copy())
    # The index is not content.
    assert data_hash(frame) == data_hash(frame.set_axis(np.arange(len(frame)) + 7))


def test_data_hash_changes_with_any_value_name_or_dtype(tmp_path):
    frame = read_readings(write(tmp_path, table()))
    base = data_hash(frame)
    changed = frame.copy()
    changed.loc[5, "deviation_um"] += 1e-9
    relabelled = frame.copy()
    relabelled.loc[0, "test_id"] = "T9"
    renamed = frame.rename(columns={"feed_mm_min": "feed"})
    retyped = frame.astype({"cycle": "int32"})
    reordered = frame[[*frame.columns[1:], frame.columns[0]]]
    hashes = [data_hash(f) for f in (changed, relabelled, renamed, retyped, reordered)]
    assert base not in hashes
    assert len(set(hashes)) == len(hashes)


# --------------------------------------------------------------------------- numbers


def test_to_float_parses_text_once_per_value_with_the_row_of_the_first_bad_one():
    text = pd.Series(["1.5", " 2", "1.5", "x", "1.5", "x"], dtype="str")
    with pytest.raises(InputError, match=r"row 13, column 'target': 'x' is not a number"):
        to_float(text, Path("f.csv"), "target", 10)
    good = to_float(pd.Series(["1.5", " 2", "1.5", "nan", ""], dtype="str",
                              index=[4, 3, 2, 1, 0]), Path("f.csv"), "feed_mm_min", 2,
                    allow_nan=True)
    assert list(good.index) == [4, 3, 2, 1, 0] and good.dtype == float
    np.testing.assert_array_equal(good.to_numpy(), [1.5, 2.0, 1.5, np.nan, np.nan])


@pytest.mark.parametrize("dtype", ["str", object])
def test_to_float_same_answers_for_text_and_object_columns(dtype):
    rows = pd.Series([7, 8, 9, 10])
    values = ["3", "4.25", "3", ""]
    got = to_float(pd.Series(values, dtype=dtype), Path("f"), "dwell_s", rows, allow_nan=True)
    np.testing.assert_array_equal(got.to_numpy(), [3.0, 4.25, 3.0, np.nan])
    with pytest.raises(InputError, match=r"row 10, column 'dwell_s': missing value \(NaN\)"):
        to_float(pd.Series(values, dtype=dtype), Path("f"), "dwell_s", rows)
    with pytest.raises(InputError, match=r"row 8, column 'cycle': 'True' is a boolean"):
        to_float(pd.Series(["1", "True", "1"], dtype=dtype), Path("f"), "cycle", 7)
    with pytest.raises(InputError, match=r"row 9, column 'cycle': 2.5 is not a whole number"):
        to_int(pd.Series(["1", "1", "2.5", "2.5"], dtype=dtype), Path("f"), "cycle", 7)


def test_repeated_bad_number_in_a_file_names_its_first_row(tmp_path):
    frame = table().astype({"deviation_um": object})
    frame.loc[[4, 9, 20], "deviation_um"] = "oops"
    with pytest.raises(InputError, match=r"row 6, column 'deviation_um': 'oops' is not"):
        read_readings(write(tmp_path, frame))


# --------------------------------------------------------------------------- blank lines


def test_blank_lines_keep_row_numbers_and_a_blank_first_cell_is_no_blank_line(tmp_path):
    lines = write(tmp_path, table()).read_text().splitlines()
    path = tmp_path / "blank.csv"
    path.write_text("\n".join([*lines[:4], "", " , ,", *lines[4:]]) + "\n")
    frame = read_readings(path)
    assert len(frame) == len(table())
    bad = lines[:4] + ["," + lines[4].split(",", 1)[1]] + lines[5:]
    path.write_text("\n".join([*bad[:2], "", *bad[2:]]) + "\n")
    with pytest.raises(InputError, match=r"row 6, column 'machine_id': empty machine_id"):
        read_readings(path)


# --------------------------------------------------------------------------- per-test checks


def test_per_test_checks_group_by_all_four_test_keys(tmp_path):
    # The same test_id on two machines is two tests; a duplicate only within one test.
    frame = table(tests=1)
    other = frame.assign(machine_id="M2")
    read_readings(write(tmp_path, pd.concat([frame, other], ignore_index=True)))
    dup = pd.concat([frame, other, other.iloc[[3]]], ignore_index=True)
    with pytest.raises(InputError, match=rf"row {len(dup) + 1}, column 'cycle': duplicate"):
        read_readings(write(tmp_path, dup, "dup.csv"))
    mixed = pd.concat([frame, other.assign(method=["pendulum"] + ["linear"] * 17)],
                      ignore_index=True)
    with pytest.raises(InputError, match="mixes linear and pendulum"):
        read_readings(write(tmp_path, mixed, "mixed.csv"))
    one_way = pd.concat([frame, other[~((other.target == 50.0) & (other.direction == "-"))]],
                        ignore_index=True)
    with pytest.raises(InputError, match=r"target 50 of test 'T1' is measured in direction "
                                         r"'\+' only"):
        read_readings(write(tmp_path, one_way, "one_way.csv"))
