"""Renishaw ``.rtl`` input: a file written by hand from the description, round trips, bad files."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from features import iso230
from features.readings import read_readings
from features.readings.errors import InputError
from features.readings.rtl import write_rtl
from pipeline.cli import main

# 3 targets, 2 cycles (4 runs). Run 1 goes up (targets 1..3), run 2 down (3..1); the
# deviation lines of runs 2 and 4 are listed in travel order, run 3's are shuffled: the reader
# must index by target number. USER-TEXT is Latin-1 (the 'ö').
HAND = (
    "HEADER::\r\n"
    "Some header line the reader skips\r\n"
    "\r\n"
    "USER-TEXT::\r\n"
    "Machine: Fräse 7\r\n"
    "Serial No: 4711\r\n"
    "Date: 12/03/2024\r\n"
    "Axis: y\r\n"
    "\r\n"
    "TARGET DATA::\r\n"
    "Target-count:3\r\n"
    "Targets :\r\n"
    "0.000000 100.000000\r\n"
    "200.000000\r\n"
    "\r\n"
    "RUNS::\r\n"
    "Run-count:4\r\n"
    "\r\n"
    "DEVIATIONS::\r\n"
    "Run Target Data:\r\n"
    "1 1 -1.0\r\n"
    "1 2 -0.5\r\n"
    "1 3 0.0\r\n"
    "2 3 4.0\r\n"
    "2 2 3.5\r\n"
    "2 1 3.0\r\n"
    "3 2 -0.7\r\n"
    "3 3 0.2\r\n"
    "3 1 -1.2\r\n"
    "4 3 4.2\r\n"
    "4 2 3.3\r\n"
    "4 1 3.0\r\n"
).encode("latin-1")


@pytest.fixture
def hand_file(tmp_path):
    path = tmp_path / "laser_test.rtl"
    path.write_bytes(HAND)
    return path


def test_hand_written_file_reads_as_described(hand_file):
    r = read_readings(hand_file)
    assert set(r["machine_id"]) == {"Fräse 7"} and set(r["axis"]) == {"Y"}
    assert len(r) == 12 and set(r["method"]) == {"linear"}
    at = r.set_index(["cycle", "direction", "target"])["deviation_um"]
    assert at[(1, "+", 0.0)] == -1.0 and at[(1, "-", 200.0)] == 4.0
    assert at[(2, "+", 100.0)] == -0.7 and at[(2, "-", 0.0)] == 3.0
    per = iso230.per_target(r).set_index("target")
    # hand-checked: target 100: up (-0.5, -0.7) mean -0.6, down (3.5, 3.3) mean 3.4
    assert per.loc[100.0, "mean_up"] == pytest.approx(-0.6)
    assert per.loc[100.0, "B_i"] == pytest.approx(-4.0)
    assert per.loc[200.0, "B_i"] == pytest.approx(0.1 - 4.1)


def test_detected_by_content_without_the_suffix(hand_file, tmp_path):
    other = tmp_path / "export.txt"
    other.write_bytes(HAND.replace(b"\r\n", b"\n"))  # LF line ends are read too
    assert len(read_readings(other)) == len(read_readings(hand_file, "rtl")) == 12


def test_descending_target_list_makes_odd_runs_go_down(tmp_path):
    text = HAND.decode("latin-1").replace("0.000000 100.000000\r\n200.000000",
                                          "200.000000 100.000000\r\n0.000000")
    path = tmp_path / "down.rtl"
    path.write_bytes(text.encode("latin-1"))
    r = read_readings(path)
    first = r[(r["cycle"] == 1) & (r["target"] == 200.0)].set_index("direction")["deviation_um"]
    assert first["-"] == -1.0  # run 1, target number 1 (200 mm), approached moving down


@pytest.mark.parametrize("fixture", ["ess_file", "psi_file"])
def test_rtl_round_trip_gives_the_same_iso_figures(fixture, request, tmp_path):
    canonical = read_readings(request.getfixturevalue(fixture))
    path = write_rtl(canonical, tmp_path / "round.rtl")
    again = read_readings(path)
    a, b = iso230.axis_figures(canonical), iso230.axis_figures(again)
    for figure in iso230.AXIS_FIGURES:
        assert b[figure].iloc[0] == pytest.approx(a[figure].iloc[0], abs=1e-6), figure
    pa, pb = iso230.per_target(canonical), iso230.per_target(again)
    assert np.allclose(pa["B_i"], pb["B_i"], atol=1e-6)


def test_twin_test_round_trip(tmp_path):
    from models.physics.campaign import simulate

    sim = simulate({"system": "indirect", "plan": {"feeds_mm_min": [500.0], "dwells_s": [3.0],
                                                   "repeats": 1, "methods": ["linear"],
                                                   "n_targets": 12, "irregular": True}}, 3)
    path = write_rtl(sim.readings, tmp_path / "twin.rtl")
    a = iso230.axis_figures(sim.readings)
    b = iso230.axis_figures(read_readings(path))
    assert np.allclose(a[list(iso230.AXIS_FIGURES)].to_numpy(float),
                       b[list(iso230.AXIS_FIGURES)].to_numpy(float), atol=1e-6)


BAD = [
    (lambda t: t.replace("DEVIATIONS::", "DEVIATION::"), "missing section DEVIATIONS::"),
    (lambda t: t.replace("Target-count:3", "Target-count:4"), "3 target positions; Target-count says 4"),
    (lambda t: t.replace("Target-count:3", "Target-count:two"), "Target-count 'two' is not a whole number"),
    (lambda t: t.replace("Run-count:4", "Run-count:3"), "Run-count 3 is odd"),
    (lambda t: t.replace("3 2 -0.7", "3 1 -0.7"), "run 3 target 1 appears twice"),
    (lambda t: t.replace("4 1 3.0\r\n", ""), "no deviation for run 4 target 1"),
    (lambda t: t.replace("2 2 3.5", "2 5 3.5"), "target '5': expected a number from 1 to 3"),
    (lambda t: t.replace("2 2 3.5", "2 2 abc"), "deviation: 'abc' is not a number"),
    (lambda t: t.replace("2 2 3.5", "2 2"), "expected 'run target deviation'"),
    (lambda t: t.replace("Targets :", "Positions :"), "no 'Targets :' line"),
    (lambda t: t.replace("Run Target Data:", "Data:"), "no 'Run Target Data:' line"),
    (lambda t: t.replace("100.000000", "0.000000"), "target positions repeat"),
]


@pytest.mark.parametrize("edit, message", BAD)
def test_unexpected_content_is_one_line_error(edit, message, tmp_path, capsys):
    path = tmp_path / "bad.rtl"
    path.write_bytes(edit(HAND.decode("latin-1")).encode("latin-1"))
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_readings(path)
    assert main(["iso", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "bad.rtl" in err


def test_writer_refuses_more_than_one_test(ess_file, psi_file, tmp_path):
    both = pd.concat([read_readings(ess_file), read_readings(psi_file)])
    with pytest.raises(InputError, match="one test"):
        write_rtl(both, tmp_path / "x.rtl")
    assert not (tmp_path / "x.rtl").exists()
