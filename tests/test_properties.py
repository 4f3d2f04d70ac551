"""Property-based checks of the readings contract: generated malformed tables are refused by
``convert``, ``iso`` and ``train`` with one line, exit code 2 and no output; generated valid
tables convert without loss (CSV and Parquet)."""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from features.readings import read_readings
from pipeline.cli import main

SETTINGS = settings(max_examples=15, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])
LABEL = st.text("ABCDEFGHJKMNPQRSTUVWXYZabcdefghjkmnpqrstuvwxyz0123456789_-", min_size=1,
                max_size=8)


@st.composite
def valid_tables(draw) -> pd.DataFrame:
    """One or two tests, 2-5 targets, both directions, 2-4 cycles, deviations of 1-50 um
    (so that a unit mistake of 1000x is detectable), a feed rate and a visit."""
    rows = []
    axis = draw(st.sampled_from("XYZABC"))
    machine = draw(LABEL)
    targets = draw(st.lists(st.integers(0, 800).map(lambda v: v * 0.5), min_size=2,
                            max_size=5, unique=True))
    cycles = draw(st.integers(2, 4))
    for test in range(draw(st.integers(1, 2))):
        method = draw(st.sampled_from(["linear", "pendulum"]))
        feed = draw(st.sampled_from([200.0, 500.0, 1200.0]))
        visit = str(draw(st.integers(1, 3)))
        points = [(d, t) for d in "+-" for t in targets]
        # Each point: a systematic deviation of 1-50 um, repeated within +-5 % by each cycle.
        base = draw(st.lists(st.floats(1.0, 50.0).map(float), min_size=len(points),
                             max_size=len(points)))
        signs = draw(st.lists(st.sampled_from([-1.0, 1.0]), min_size=len(points),
                              max_size=len(points)))
        for cycle in range(1, cycles + 1):
            spread = draw(st.lists(st.floats(-0.05, 0.05), min_size=len(points),
                                   max_size=len(points)))
            for (direction, target), size, sign, noise in zip(points, base, signs, spread):
                rows.append({"machine_id": machine, "axis": axis, "test_id": f"T{test}",
                             "method": method, "target": target, "direction": direction,
                             "cycle": cycle, "deviation_um": sign * size * (1 + noise),
                             "feed_mm_min": feed, "visit": visit})
    return pd.DataFrame(rows)


def _set(frame, row, col, value):
    frame = frame.astype({col: object}) if col in frame else frame
    frame.loc[row, col] = value
    return frame


def _mixed_units(frame, row):
    """One reading written in mm among readings in um (1000x too small), or in deg among
    arcsec on a rotary axis (3600x)."""
    value = frame.loc[row, "deviation_um"]
    factor = 3600.0 if frame.loc[row, "axis"] in ("A", "B", "C") else 1000.0
    return _set(frame.assign(deviation_um=frame["deviation_um"]), row, "deviation_um",
                value / factor if abs(value) >= 1.0 else value * factor)


# name -> (mutation(frame, row, data) -> frame, or text edit, words expected in the line)
MUTATIONS = {
    "missing_column": lambda f, r, d: f.drop(columns=d.draw(st.sampled_from(
        ["machine_id", "axis", "test_id", "method", "target", "direction", "cycle",
         "deviation_um"]))),
    "text_in_number": lambda f, r, d: _set(f, r, d.draw(st.sampled_from(
        ["target", "deviation_um", "cycle", "feed_mm_min"])), d.draw(st.sampled_from(
            ["abc", "1,5", "12 um", "25.21 mm", "--3", "0x10"]))),
    "nan": lambda f, r, d: _set(f, r, d.draw(st.sampled_from(
        ["target", "deviation_um", "cycle"])), d.draw(st.sampled_from(["", "NaN", "nan"]))),
    "infinite": lambda f, r, d: _set(f, r, d.draw(st.sampled_from(
        ["target", "deviation_um", "feed_mm_min"])), d.draw(st.sampled_from(["inf", "-inf"]))),
    "boolean": lambda f, r, d: _set(f, r, d.draw(st.sampled_from(
        ["target", "deviation_um", "feed_mm_min"])), d.draw(st.sampled_from(["true", "False"]))),
    "wrong_label": lambda f, r, d: _set(f, r, *d.draw(st.sampled_from(
        [("direction", "sideways"), ("direction", "0"), ("method", "spiral"),
         ("axis", "Q"), ("axis", "XY"), ("machine_id", " ")]))),
    "fractional_index": lambda f, r, d: _set(f, r, d.draw(st.sampled_from(["cycle", "repeat"])),
                                             d.draw(st.sampled_from([1.5, 0.0, -1.0, 2.25]))),
    "duplicate_row": lambda f, r, d: pd.concat([f, f.iloc[[r]]], ignore_index=True),
    "one_direction": lambda f, r, d: f[~((f["target"] == f.loc[r, "target"])
                                          & (f["direction"] == f.loc[r, "direction"]))],
    "single_cycle": lambda f, r, d: f[f["cycle"] == 1],
    "mixed_units": lambda f, r, d: _mixed_units(f, r),
    "deviation_in_mm": lambda f, r, d: f.assign(deviation_um=f["deviation_um"] / 1e5),
    "case_duplicate_header": lambda f, r, d: f.assign(Target=f["target"]),
    "implausible_condition": lambda f, r, d: _set(f, r, *d.draw(st.sampled_from(
        [("feed_mm_min", 0.0), ("pressure_hpa", 101325.0), ("humidity_pct", 140.0)]))),
}
TEXT_MUTATIONS = ("latin1", "semicolons", "tabs", "empty", "header_only", "binary")


def _text_mutation(name: str, text: str, row: int) -> bytes:
    lines = text.splitlines()
    if name == "latin1":
        lines[row] = lines[row] + "é"
        return ("\n".join(lines) + "\n").encode("latin-1")
    if name == "semicolons":
        return text.replace(",", ";").encode()
    if name == "tabs":
        return text.replace(",", "\t").encode()
    if name == "empty":
        return b""
    if name == "header_only":
        return (lines[0] + "\n").encode()
    return b"\x89PNG\r\n\x1a\n\x00\x00" + text.encode()


KINDS = sorted(MUTATIONS) + list(TEXT_MUTATIONS)


@st.composite
def malformed_files(draw, kind: str | None = None) -> tuple[str, bytes]:
    """A valid table with one mistake of ``kind`` (any kind when None)."""
    frame = draw(valid_tables())
    row = draw(st.integers(0, len(frame) - 1))
    name = kind or draw(st.sampled_from(KINDS))
    if name in TEXT_MUTATIONS:
        return name, _text_mutation(name, frame.to_csv(index=False), row + 1)
    return name, MUTATIONS[name](frame, row, draw(st.data())).to_csv(index=False).encode()


def run_cli(argv: list[str]) -> tuple[int, list[str]]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as stop:
            code = stop.code
    return code, [line for line in err.getvalue().splitlines() if line.strip()]


def assert_refused(command: str, extra: list[str], case, outputs: list[Path], folder: Path):
    name, content = case
    path = folder / "readings.csv"
    path.write_bytes(content)
    code, err = run_cli([command, str(path), *extra])
    assert code == 2, (name, err)
    # one line, no note before it: the CLI shows notes only after a command succeeds
    assert len(err) == 1 and err[0].startswith(f"backlash {command}: error: "), (name, err)
    assert str(path) in err[0], (name, err)
    assert not any(p.exists() for p in outputs), name
    assert sorted(p.name for p in folder.iterdir()) == ["readings.csv"], name


@pytest.mark.parametrize("kind", KINDS)
def test_convert_refuses_every_kind_of_malformed_table(kind):
    @settings(SETTINGS, max_examples=4)
    @given(malformed_files(kind))
    def check(case):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out" / "readings.csv"
            assert_refused("convert", ["--out", str(out)], case, [out.parent], Path(tmp))

    check()


@SETTINGS
@given(malformed_files())
def test_iso_refuses_malformed_tables(case):
    with tempfile.TemporaryDirectory() as tmp:
        plot = Path(tmp) / "charts" / "iso.png"
        assert_refused("iso", ["--json", "--plot", str(plot)], case, [plot.parent], Path(tmp))


@settings(SETTINGS, max_examples=8)
@given(malformed_files())
def test_train_refuses_malformed_tables(case):
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "model"
        assert_refused("train", ["--out", str(out)], case, [out], Path(tmp))


@SETTINGS
@given(valid_tables(), st.sampled_from([".csv", ".parquet"]))
def test_valid_tables_convert_without_loss(frame, suffix):
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "readings.csv"
        frame.to_csv(source, index=False)
        out = Path(tmp) / f"converted{suffix}"
        code, err = run_cli(["convert", str(source), "--out", str(out)])
        assert code == 0, err
        back = read_readings(out)
    assert len(back) == len(frame)
    keys = ["test_id", "cycle", "direction", "target"]
    back = back.sort_values(keys).reset_index(drop=True)
    want = frame.sort_values(keys).reset_index(drop=True)
    for col in ("machine_id", "axis", "test_id", "method", "direction", "visit"):
        assert back[col].tolist() == want[col].astype(str).tolist(), col
    for col in ("target", "deviation_um", "feed_mm_min"):
        np.testing.assert_array_equal(back[col].to_numpy(), want[col].to_numpy(), col)
    np.testing.assert_array_equal(back["cycle"].to_numpy(), want["cycle"].to_numpy())
