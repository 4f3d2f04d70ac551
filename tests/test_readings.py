"""Readings I/O: the three layouts, aliases, unit handling, and every bad input we refuse."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features.readings import read_readings, write_readings
from features.readings.errors import BacklashWarning
from features.readings.formats import _read_plain_csv
from pipeline.cli import main

TARGETS = (0.0, 50.0, 100.0)


def valid_table(cycles: int = 3, method: str = "linear") -> pd.DataFrame:
    """A small canonical test: 3 targets x 2 directions x 3 cycles, B_i = -4 um."""
    rows = []
    for cycle in range(1, cycles + 1):
        for direction, offset in (("+", -2.0), ("-", 2.0)):
            for target in TARGETS:
                rows.append({
                    "machine_id": "M1", "axis": "X", "test_id": "T1", "method": method,
                    "target": target, "direction": direction, "cycle": cycle,
                    "deviation_um": 0.01 * target + offset + 0.1 * cycle,
                    "feed_mm_min": 500.0, "pressure_hpa": 1013.0,
                })
    return pd.DataFrame(rows)


def write_csv(tmp_path, frame: pd.DataFrame, name: str = "readings.csv"):
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


def convert(tmp_path, path, capsys, *extra):
    """Run `backlash convert` and return (exit code, stderr lines, output path)."""
    out = tmp_path / "out" / "converted.csv"
    code = main(["convert", str(path), "--out", str(out), *extra])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, err, out


# ------------------------------------------------------------------------ good input


def test_canonical_csv_round_trip_through_parquet(tmp_path):
    frame = read_readings(write_csv(tmp_path, valid_table()))
    assert list(frame.columns[:8]) == ["machine_id", "axis", "test_id", "method", "target",
                                       "direction", "cycle", "deviation_um"]
    assert frame["visit"].eq("1").all() and frame["repeat"].eq(1).all()
    write_readings(frame, tmp_path / "r.parquet")
    again = read_readings(tmp_path / "r.parquet")
    pd.testing.assert_frame_equal(frame.reset_index(drop=True), again, check_dtype=False)


@pytest.mark.parametrize("variant", ["quoted", "space after comma", "blank line", "bom"])
def test_fast_and_general_csv_readers_give_the_same_readings(tmp_path, variant):
    """A plain CSV goes through Arrow's reader; a quote, a space after a delimiter or a
    byte-order mark sends the file to pandas' reader: both read the same readings, and a blank
    line keeps the row numbers of the lines after it."""
    plain = write_csv(tmp_path, valid_table(), "plain.csv")
    lines = plain.read_text().splitlines()
    if variant == "quoted":
        lines[1] = lines[1].replace("M1", '"M1"', 1)
    elif variant == "space after comma":
        lines[1] = lines[1].replace(",", ", ")
    elif variant == "blank line":
        lines.insert(2, "")
    other = tmp_path / "other.csv"
    other.write_text(("\ufeff" if variant == "bom" else "") + "\n".join(lines) + "\n",
                     encoding="utf-8")
    assert _read_plain_csv(plain) is not None
    # Arrow reads a blank line as a row of empty cells, which is dropped as pandas' NaN row is
    assert (_read_plain_csv(other) is None) == (variant != "blank line")
    fast, general = read_readings(plain), read_readings(other)
    pd.testing.assert_frame_equal(fast, general)
    # row numbers in errors: a bad value after the blank line is on the line it is written
    if variant == "blank line":
        lines[4] = lines[4].replace("X", "Q", 1)
        other.write_text("\n".join(lines) + "\n")
        with pytest.raises(Exception, match="row 5"):
            read_readings(other)


def test_aliases_are_normalised(tmp_path):
    table = valid_table()
    table["direction"] = table["direction"].map({"+": "FWD", "-": "down"})
    table["method"] = "Lin"
    table.loc[0, "direction"] = "+1"
    frame = read_readings(write_csv(tmp_path, table))
    assert set(frame["direction"]) == {"+", "-"} and set(frame["method"]) == {"linear"}
    assert (frame.loc[frame["direction"] == "+", "deviation_um"]
            < frame.loc[frame["direction"] == "-", "deviation_um"].mean()).all()


def test_measured_column_gives_deviation_in_um(tmp_path):
    table = valid_table()
    table["measured"] = table["target"] + table["deviation_um"] / 1000.0
    frame = read_readings(write_csv(tmp_path, table.drop(columns="deviation_um")))
    np.testing.assert_allclose(frame["deviation_um"], table["deviation_um"], atol=1e-9)


def test_rotary_axis_measured_in_degrees_gives_arcsec(tmp_path):
    table = valid_table().assign(axis="C")
    table["measured"] = table["target"] + table["deviation_um"] / 3600.0
    frame = read_readings(write_csv(tmp_path, table.drop(columns="deviation_um")))
    np.testing.assert_allclose(frame["deviation_um"], table["deviation_um"], atol=1e-9)


def test_ecmc_forward_is_plus_direction(ess_file):
    frame = read_readings(ess_file)
    first = frame[(frame["direction"] == "+") & (frame["target"] == 15.0) & (frame["cycle"] == 1)]
    # REF_DATA_FWD[1,1]=15.0931842960383320 with TGT_DATA[1]=15
    assert first["deviation_um"].item() == pytest.approx(93.184296038332, abs=1e-9)
    assert len(frame) == 50 and frame["method"].eq("linear").all()


def test_paper_table_absolute_rows_are_converted_with_a_warning(tmp_path, capsys):
    # Rows shaped like the paper's Table 2: two rows of deviations, two rows of positions.
    wide = pd.DataFrame({
        "No": [1, 2, 3, 4],
        "Pos. [mm]": [250, 250, 250, 250],
        "Dev_lin_f [mm]": [-0.0172, -0.0169, 249.9828, 249.9831],
        "Dev_lin_r [mm]": [-0.0235, -0.0233, 249.9765, 249.9767],
        "Speed [mm/min]": [500, 500, 500, 500],
        "T_e [°C]": [26.9] * 4,
        "Dev_pend_f [mm]": [0.024, 0.0243, 250.024, 250.0243],
        "Dev_pend_r [mm]": [0.0181, 0.0173, 250.0181, 250.0173],
    })
    with pytest.warns(BacklashWarning, match="8 cells of the deviation columns hold absolute "
                      "positions"):
        frame = read_readings(write_csv(tmp_path, wide, "table2.csv"))
    lin_up = frame[(frame["method"] == "linear") & (frame["direction"] == "+")]
    np.testing.assert_allclose(lin_up["deviation_um"], [-17.2, -16.9, -17.2, -16.9], atol=1e-6)
    assert sorted(frame["cycle"].unique()) == [1, 2, 3, 4]
    assert frame["ambient_temp_c"].eq(26.9).all() and frame["feed_mm_min"].eq(500).all()
    assert set(frame["method"]) == {"linear", "pendulum"}


def test_convert_writes_parquet(tmp_path, capsys, psi_file):
    out = tmp_path / "psi.parquet"
    assert main(["convert", str(psi_file), "--out", str(out)]) == 0
    assert len(pd.read_parquet(out)) == 50


# ------------------------------------------------------------------------ bad input


def _csv_text(tmp_path, text: str, name: str = "bad.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _edit(tmp_path, edit):
    table = valid_table()
    table = edit(table)
    return write_csv(tmp_path, table, "bad.csv")


def _set(row, col, value):
    def edit(t):
        t = t.astype({col: object})
        t.loc[row, col] = value
        return t
    return edit


BAD_TABLES = {
    # name: (edit of a valid table, expected words in the message, column, data row or None)
    "missing_required_column": (lambda t: t.drop(columns="cycle"), "missing required column",
                                "cycle", None),
    "unknown_direction": (_set(4, "direction", "sideways"), "unknown direction", "direction", 4),
    "unknown_method": (_set(2, "method", "spiral"), "unknown method", "method", 2),
    "nan_deviation": (_set(5, "deviation_um", ""), "missing value", "deviation_um", 5),
    "non_numeric_target": (_set(3, "target", "fifty"), "not a number", "target", 3),
    "fractional_cycle": (_set(1, "cycle", 1.5), "whole number", "cycle", 1),
    "unknown_axis": (lambda t: t.assign(axis="Q"), "unknown axis", "axis", 0),
    "no_deviation_or_measured": (lambda t: t.drop(columns="deviation_um"), "deviation_um",
                                 "deviation_um", None),
    "duplicate_reading": (lambda t: pd.concat([t, t.iloc[[7]]], ignore_index=True),
                          "duplicate reading", "cycle", 18),
    "one_direction_only": (lambda t: t[~((t["target"] == 50.0) & (t["direction"] == "-"))],
                           "only", "direction", None),
    "fewer_than_two_cycles": (lambda t: t[t["cycle"] == 1], "at least 2 cycles", "cycle", None),
    "mixed_methods_in_one_test": (_set(0, "method", "pendulum"), "mixes linear and pendulum",
                                  "method", None),
    "mixed_units": (_set(9, "deviation_um", 0.0025), "mixed units", "deviation_um", 9),
    "deviation_in_mm": (lambda t: t.assign(deviation_um=t["deviation_um"] / 1000.0),
                        "look like mm", "deviation_um", 0),
    "measured_in_um": (lambda t: t.drop(columns="deviation_um").assign(
        measured=(t["target"] * 1000.0 + t["deviation_um"])), "expected a position in mm",
        "measured", 0),
    "pressure_in_pa": (_set(6, "pressure_hpa", 101325.0), "hPa", "pressure_hpa", 6),
    "zero_feed": (_set(0, "feed_mm_min", 0.0), "feed rate", "feed_mm_min", 0),
    "bad_date": (lambda t: t.assign(started_at="2026-13-45"), "ISO 8601", "started_at", 0),
    "empty_machine_id": (_set(3, "machine_id", ""), "empty machine_id", "machine_id", 3),
}


@pytest.mark.parametrize("case", sorted(BAD_TABLES))
def test_bad_table_gives_one_line_exit_2_and_no_output(tmp_path, capsys, case):
    edit, words, column, data_row = BAD_TABLES[case]
    path = _edit(tmp_path, edit)
    code, err, out = convert(tmp_path, path, capsys)
    assert code == 2
    assert len(err) == 1, err
    assert str(path) in err[0] and words in err[0]
    assert f"column {column!r}" in err[0]
    if data_row is not None:
        assert f"row {data_row + 2}," in err[0]  # header is row 1
    assert not out.exists() and not any(out.parent.glob("*")) if out.parent.exists() else True


@pytest.mark.parametrize("case, text, words", [
    ("empty_file", "", "empty file"),
    ("header_only", "machine_id,axis,test_id,method,target,direction,cycle,deviation_um\n",
     "no data rows"),
    ("semicolon_delimiter", ("machine_id;axis;test_id;method;target;direction;cycle;deviation_um\n"
                             "M;X;T;linear;0;+;1;1.0\n"), "semicolons"),
    ("unknown_layout", "time,value\n1,2\n", "unknown format"),
    ("malformed_csv", ("machine_id,axis,test_id,method,target,direction,cycle,deviation_um\n"
                       'M,X,T,linear,0,+,1,"1.0\n'), "malformed CSV"),
])
def test_bad_file_gives_one_line_exit_2(tmp_path, capsys, case, text, words):
    path = _csv_text(tmp_path, text)
    code, err, out = convert(tmp_path, path, capsys)
    assert code == 2 and len(err) == 1 and words in err[0] and str(path) in err[0], err
    assert not out.exists()


def test_missing_file(tmp_path, capsys):
    code, err, _ = convert(tmp_path, tmp_path / "nope.csv", capsys)
    assert code == 2 and "no such file" in err[0] and "nope.csv" in err[0]


def test_binary_file(tmp_path, capsys):
    path = tmp_path / "image.csv"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00")
    code, err, _ = convert(tmp_path, path, capsys)
    assert code == 2 and "binary" in err[0]


def test_broken_parquet(tmp_path, capsys):
    path = tmp_path / "broken.parquet"
    path.write_text("not parquet")
    code, err, _ = convert(tmp_path, path, capsys)
    assert code == 2 and "cannot read Parquet" in err[0] and len(err) == 1


def test_unknown_output_type_writes_nothing(tmp_path, capsys):
    path = write_csv(tmp_path, valid_table())
    code = main(["convert", str(path), "--out", str(tmp_path / "x.xlsx")])
    assert code == 2 and "expected a .csv or .parquet" in capsys.readouterr().err
    assert not (tmp_path / "x.xlsx").exists()


def test_unknown_format_option_is_refused(tmp_path, capsys):
    path = write_csv(tmp_path, valid_table())
    assert main(["convert", str(path), "--format", "excel", "--out", str(tmp_path / "o.csv")]) == 2
    assert "invalid choice: 'excel'" in capsys.readouterr().err


def test_ecmc_reference_without_target(tmp_path, capsys):
    path = _csv_text(tmp_path, "UNIT=mm\nTGT_DATA[1]=0\nREF_DATA_FWD[2,1]=1.0\n", "x_ISO230.dat")
    code, err, _ = convert(tmp_path, path, capsys)
    assert code == 2 and "TGT_DATA[2]" in err[0]


def test_ecmc_non_numeric_value_names_the_line(tmp_path, capsys):
    path = _csv_text(tmp_path, "UNIT=mm\nTGT_DATA[1]=0\nREF_DATA_FWD[1,1]=abc\n", "y_ISO230.dat")
    code, err, _ = convert(tmp_path, path, capsys)
    assert code == 2 and "row 3" in err[0] and "'abc' is not a number" in err[0]


def test_paper_table_missing_column(tmp_path, capsys):
    path = _csv_text(tmp_path, "Pos. [mm],Dev_lin_f [mm],Dev_lin_r [mm]\n0,0.001,0.002\n")
    code, err, _ = convert(tmp_path, path, capsys, "--format", "paper")
    assert code == 2 and "missing paper Table-2 column 'dev_pend_f_mm'" in err[0]


# ------------------------------------------------------------ hostile and careless input


def _refused(tmp_path, capsys, path, *words, row=None, column=None, extra=()):
    """convert refuses ``path``: exit 2, one line naming the file and ``words``, no output."""
    code, err, out = convert(tmp_path, path, capsys, *extra)
    assert code == 2, err
    assert len(err) == 1, err
    assert err[0].startswith("backlash convert: error: ") and str(path) in err[0], err
    for word in words:
        assert word in err[0], err
    if row is not None:
        assert f"row {row}" in err[0], err
    if column is not None:
        assert f"column {column!r}" in err[0], err
    assert not out.exists() and not out.parent.exists()
    return err[0]


def _ecmc(tmp_path, lines: list[str], name: str = "m_ISO230.dat"):
    """A small ecmc file: 2 targets x 2 directions x 2 cycles, then ``lines`` replace/add."""
    base = {"UNIT": "UNIT=mm", "TGT_DATA[1]": "TGT_DATA[1]=0", "TGT_DATA[2]": "TGT_DATA[2]=10"}
    for pos, target in ((1, 0.0), (2, 10.0)):
        for way, sign in (("FWD", -1), ("BWD", 1)):
            for cycle in (1, 2):
                key = f"REF_DATA_{way}[{pos},{cycle}]"
                base[key] = f"{key}={target + sign * 0.002 + cycle * 1e-4:.6f}"
    for line in lines:
        base[line.split("=")[0].strip()] = line
    return _csv_text(tmp_path, "\n".join(base.values()) + "\n", name)


def test_latin1_byte_after_the_first_8_kb_names_its_row(tmp_path, capsys):
    table = pd.concat([valid_table().assign(test_id=f"T{i}") for i in range(40)])
    text = table.to_csv(index=False)
    assert len(text) > 8192
    lines = text.splitlines()
    lines[500] = lines[500].replace("M1", "Mé", 1)
    path = tmp_path / "latin1.csv"
    path.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    _refused(tmp_path, capsys, path, "byte 0xe9", "not UTF-8", "save the file as UTF-8",
             row=501)


def test_utf16_with_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "utf16.csv"
    path.write_bytes(valid_table().to_csv(index=False).encode("utf-16"))
    frame = read_readings(path)
    np.testing.assert_allclose(frame["deviation_um"], valid_table()["deviation_um"])


def test_headers_differing_only_in_case_are_refused(tmp_path, capsys):
    table = valid_table()
    table["Target"] = table["target"] + 1.0
    _refused(tmp_path, capsys, write_csv(tmp_path, table), "'target' and 'Target'",
             "differ only in case", row=1)


def test_exact_duplicate_header_is_refused(tmp_path, capsys):
    text = valid_table().to_csv(index=False).replace("pressure_hpa", "target", 1)
    _refused(tmp_path, capsys, _csv_text(tmp_path, text), "'target' appears twice", row=1)


def test_boolean_text_in_a_numeric_column_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _edit(tmp_path, _set(3, "deviation_um", "true")),
             "'true' is a boolean", row=5, column="deviation_um")


def test_boolean_parquet_column_is_not_read_as_0_1_um(tmp_path, capsys):
    table = valid_table()
    table["deviation_um"] = [True, False] * 9
    path = tmp_path / "bools.parquet"
    table.to_parquet(path)
    _refused(tmp_path, capsys, path, "True is a boolean", column="deviation_um")


def test_fractional_repeat_is_refused_not_truncated(tmp_path, capsys):
    _refused(tmp_path, capsys, _edit(tmp_path, lambda t: t.assign(repeat=1.5)),
             "1.5 is not a whole number", row=2, column="repeat")


def test_huge_cycle_index_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _edit(tmp_path, _set(2, "cycle", "1e30")),
             "not a whole number from 1 to", row=4, column="cycle")


PAPER_ROWS = {
    "Pos. [mm]": [0, 0, 100, 100], "Dev_lin_f [mm]": [-0.0012, -0.0010, 0.0031, 0.0033],
    "Dev_lin_r [mm]": [0.0011, 0.0012, 0.0052, 0.0050],
    "Dev_pend_f [mm]": [0.0008, 0.0009, 0.0040, 0.0041],
    "Dev_pend_r [mm]": [0.0021, 0.0022, 0.0060, 0.0062], "Speed [mm/min]": [500] * 4,
}


def _paper(tmp_path, **changes):
    wide = pd.DataFrame(PAPER_ROWS)
    for col, values in changes.items():
        wide[col] = values
    return write_csv(tmp_path, wide, "table2.csv")


def test_paper_fractional_repeat_is_refused_not_truncated(tmp_path, capsys):
    _refused(tmp_path, capsys, _paper(tmp_path, repeat=[1, 1, 1.5, 1.5]),
             "1.5 is not a whole number", row=4, column="repeat")


def test_paper_deviations_in_um_in_the_mm_columns_are_refused(tmp_path, capsys):
    in_um = {c: [v * 1000 for v in PAPER_ROWS[c]] for c in PAPER_ROWS if c.startswith("Dev")}
    _refused(tmp_path, capsys, _paper(tmp_path, **in_um), "beyond 1 mm", "1000x",
             row=2, column="Dev_lin_f [mm]")


def test_paper_row_mixing_positions_and_deviations_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _paper(tmp_path, **{"Dev_lin_f [mm]": [-0.0012, -0.0010,
                                                                      100.0031, 0.0033]}),
             "other cells of this row are absolute positions", row=4, column="Dev_lin_r [mm]")


def test_paper_column_given_twice_under_two_spellings_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _paper(tmp_path, position_mm=[0, 0, 50, 50]),
             "'Pos. [mm]' and 'position_mm' both give 'position_mm'", row=1)


def test_absolute_positions_convert_the_whole_test_including_target_0(tmp_path, capsys):
    table = valid_table()
    absolute = table.assign(deviation_um=table["target"] + table["deviation_um"] / 1000.0)
    with pytest.warns(BacklashWarning, match="18 deviation_um values hold absolute positions"):
        frame = read_readings(write_csv(tmp_path, absolute))
    np.testing.assert_allclose(frame["deviation_um"], table["deviation_um"], atol=1e-6)


def test_positions_mixed_with_um_deviations_are_refused(tmp_path, capsys):
    # target 0 holds a deviation in um, the other targets positions in mm: no consistent reading
    table = valid_table()
    far = table["target"] > 0
    table.loc[far, "deviation_um"] = table.loc[far, "target"] + table.loc[far, "deviation_um"] / 1e3
    _refused(tmp_path, capsys, write_csv(tmp_path, table), "at target 50 hold absolute",
             "expected one or the other", row=3, column="deviation_um")


def test_unnamed_column_with_values_is_refused_and_empty_one_dropped(tmp_path, capsys):
    text = valid_table().to_csv(index=False)
    trailing = "\n".join(line + "," for line in text.splitlines()) + "\n"
    frame = read_readings(_csv_text(tmp_path, trailing, "trailing.csv"))
    assert not any(c.startswith("Unnamed") for c in frame.columns)
    lines = trailing.splitlines()
    lines[4] += "7"
    _refused(tmp_path, capsys, _csv_text(tmp_path, "\n".join(lines) + "\n"),
             "column 11 has values but no name", row=5)


def test_folder_given_as_input_is_refused(tmp_path, capsys):
    (tmp_path / "data.csv").mkdir()
    _refused(tmp_path, capsys, tmp_path / "data.csv", "is a folder; expected a readings file")


@pytest.mark.parametrize("value", ["nan", "NaN", "25.21 mm", "25,21", "", "0x1A"])
def test_ecmc_value_that_is_not_a_plain_number_is_refused_with_its_line(tmp_path, capsys,
                                                                          value):
    path = _ecmc(tmp_path, [f"REF_DATA_FWD[2,1]={value}"])
    _refused(tmp_path, capsys, path, "is not a number", row=8)


def test_ecmc_overflowing_value_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _ecmc(tmp_path, ["TGT_DATA[2]=1e999"]), "too large", row=3)


def test_ecmc_target_given_twice_is_refused(tmp_path, capsys):
    path = _ecmc(tmp_path, [])
    path.write_text(path.read_text() + "TGT_DATA[2]=11\n")
    _refused(tmp_path, capsys, path, "TGT_DATA[2] is given twice", row=12)


def test_ecmc_duplicate_reading_names_its_line(tmp_path, capsys):
    path = _ecmc(tmp_path, [])
    path.write_text(path.read_text() + "REF_DATA_BWD[1,2]=0.0021\n")
    _refused(tmp_path, capsys, path, "duplicate reading", row=12)


def test_ecmc_valid_small_file_converts(tmp_path):
    frame = read_readings(_ecmc(tmp_path, []))
    assert len(frame) == 8
    plus = frame[(frame["direction"] == "+") & (frame["target"] == 10.0)]
    np.testing.assert_allclose(plus["deviation_um"], [-1.9, -1.8], atol=1e-6)


def test_deviation_beyond_1_mm_is_refused(tmp_path, capsys):
    _refused(tmp_path, capsys, _edit(tmp_path, _set(7, "deviation_um", 4200.0)),
             "deviation 4200 is beyond 1 mm", row=9, column="deviation_um")


def test_mixed_units_with_two_cycles_are_refused(tmp_path, capsys):
    # The median of a pair is its mean, which the mm value drags halfway down.
    table = valid_table(cycles=2)
    row = table.index[(table["target"] == 100.0) & (table["direction"] == "-")][0]
    table.loc[row, "deviation_um"] /= 1000.0
    _refused(tmp_path, capsys, write_csv(tmp_path, table), "mixed units", row=row + 2,
             column="deviation_um")


def test_a_reading_in_degrees_among_arcsec_is_refused(tmp_path, capsys):
    """A rotary axis: 3600x, not 1000x, between the units."""
    table = valid_table(cycles=4).assign(axis="C", deviation_um=lambda t: t["deviation_um"] * 9)
    row = table.index[(table["target"] == 100.0) & (table["direction"] == "-")][1]
    table.loc[row, "deviation_um"] /= 3600.0
    _refused(tmp_path, capsys, write_csv(tmp_path, table),
             "looks like deg while the other readings at this target are about", row=row + 2,
             column="deviation_um")


def test_a_reading_near_zero_among_noisy_siblings_is_kept(tmp_path):
    """Siblings scattering by 2 um around 4 um: a reading of 0.004 um is noise, not mm."""
    table = valid_table(cycles=5)
    at = (table["target"] == 100.0) & (table["direction"] == "-")
    table.loc[at, "deviation_um"] = [0.004, 2.0, 4.5, 6.0, 3.5]
    frame = read_readings(write_csv(tmp_path, table))
    np.testing.assert_allclose(np.sort(frame.loc[
        (frame["target"] == 100.0) & (frame["direction"] == "-"), "deviation_um"]),
        [0.004, 2.0, 3.5, 4.5, 6.0])


def test_blank_lines_are_skipped_and_rows_keep_their_line_numbers(tmp_path, capsys):
    lines = valid_table().to_csv(index=False).splitlines()
    lines[6] = lines[6].replace("500.0", "fast")
    text = "\n".join(lines[:4] + ["", " , ,", *lines[4:]]) + "\n"
    _refused(tmp_path, capsys, _csv_text(tmp_path, text), "'fast' is not a number", row=9,
             column="feed_mm_min")


def test_a_user_column_named_row_is_kept(tmp_path):
    table = valid_table().assign(row=[f"r{i}" for i in range(18)])
    frame = read_readings(write_csv(tmp_path, table))
    assert frame["row"].tolist() == table["row"].tolist()


def test_measured_disagreeing_with_deviation_is_refused(tmp_path, capsys):
    table = valid_table()
    table["measured"] = table["target"] + table["deviation_um"] / 1000.0
    table.loc[4, "measured"] += 0.005  # 5 um apart
    _refused(tmp_path, capsys, write_csv(tmp_path, table), "disagrees with measured - target",
             row=6, column="deviation_um")


def test_ecmc_unit_given_twice_is_refused(tmp_path, capsys):
    path = _ecmc(tmp_path, [])
    path.write_text(path.read_text() + "UNIT=um\n")
    _refused(tmp_path, capsys, path, "UNIT is given twice (mm and um)", row=12)


@pytest.mark.parametrize("header, drop, words", [
    ("CYCLES=2", "REF_DATA_BWD[2,2]", "CYCLES=2 but position 2 BWD has 1 cycles"),
    ("CYCLES=3", None, "CYCLES=3 but position 1 BWD has 2 cycles"),
    ("POSITIONS=3", None, "POSITIONS=3 but the file has 2 TGT_DATA lines"),
])
def test_ecmc_file_shorter_than_it_declares_is_refused(tmp_path, capsys, header, drop, words):
    path = _ecmc(tmp_path, [])
    lines = [line for line in path.read_text().splitlines()
             if drop is None or not line.startswith(drop)]
    path.write_text("\n".join([header, *lines]) + "\n")
    _refused(tmp_path, capsys, path, words, row=1)


@pytest.mark.parametrize("label", ["M1\nX", "M\t1", "M1\x1b[31m"])
def test_label_with_a_control_character_is_refused(tmp_path, capsys, label):
    line = _refused(tmp_path, capsys, _edit(tmp_path, _set(2, "machine_id", label)),
                    "holds a control character", row=4, column="machine_id")
    assert "\n" not in line
