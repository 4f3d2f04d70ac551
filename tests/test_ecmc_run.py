"""A raw ecmc log of an ISO 230-2 run read as ecmc's own extraction reads it
(``ecmccomgui/tools/iso230-2``): the test number set once the axis has settled, the reading
logged last before it in the file's order, ``d c 0 p`` numbers zero-padded to the widest,
negative gear ratios; and, without test numbers, settled stops that never read the axis
while it moves. The logs are written by ``tests/camonitor_logs.py`` to that convention."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings.approaches import read_camonitor_readings
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main
from tests.camonitor_logs import run_readings, write_run
from tests.test_cli_errors import refused

PVS = {"REF_PV": "IOC_TEST:m0s005-Enc01-PosAct", "TEST_PV": "IOC_TEST:TestNumber",
       "TGT_SET_PV": "IOC_TEST:Axis1-PosSet"}
# A laser mounted the other way round: reference = (axis - 50.3) / -1.0036.
GEAR = (-1.0036, 50.3)
NINE = {i: -20.0 + 5.0 * (i - 1) for i in range(1, 10)}  # -20 .. 20 mm


def reversal(readings: pd.DataFrame) -> pd.Series:
    """B_i = mean_up - mean_down per target [um], computed here (not by the product)."""
    mean = readings.groupby(["target", "direction"])["deviation_um"].mean().unstack()
    return (mean["+"] - mean["-"]).round(9)


def truth_frame(targets: dict, readings: dict) -> pd.DataFrame:
    return pd.DataFrame([{"target": targets[i], "direction": "+" if way == "FWD" else "-",
                          "cycle": j, "measured_true": x}
                         for (way, i, j), x in readings.items()])


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Nine targets, five cycles, 34 um of lost motion, the laser's gear ratio negative, ecmc's
    resolver test after the run, three INVALID dropouts while settling."""
    folder = tmp_path_factory.mktemp("ecmc")
    truth = run_readings(NINE, 5, 0.034, seed=3)
    kwargs = {"scale": GEAR[0], "offset": GEAR[1], "speed": 20.0, "dwell": 1.5, "tail_mm": 0.8}
    with_numbers = write_run(folder / "data.log", NINE, truth, PVS, invalid=3, **kwargs)
    without = write_run(folder / "stops.log", NINE, truth, PVS, test_numbers=False, **kwargs)
    return with_numbers, without, truth


def test_test_numbers_give_the_90_readings_in_file_order(run, tmp_path, capsys):
    log, _, truth = run
    out = tmp_path / "r.csv"
    code = main(["convert", str(log), "--reference-scale", "-1.0036,50.3", "--out", str(out)])
    assert code == 0
    err = capsys.readouterr().err
    assert "3 values logged with alarm severity INVALID are not measurements" in err
    readings = pd.read_csv(out)
    assert len(readings) == 90 and set(readings["axis"]) == {"X"}
    assert set(readings["machine_id"]) == {"IOC_TEST:Axis1"}
    both = readings.merge(truth_frame(NINE, truth), on=["target", "direction", "cycle"])
    assert len(both) == 90
    # the very line before each test number: exact to the digits logged
    assert np.abs(both["measured"] - both["measured_true"]).max() < 1e-8
    assert np.allclose(reversal(readings), -34.0, atol=0.6)


def test_a_reader_sorting_by_time_would_read_the_next_move(run):
    """The test number is stamped after the controller's first samples of the next move: in
    time order those samples precede it, so the file's order is what makes the reading."""
    from features.readings.camonitor import parse_camonitor

    lines = parse_camonitor(run[0])
    test = lines[lines["pv"] == PVS["TEST_PV"]]
    later = lines[(lines["pv"] == PVS["REF_PV"])
                  & (lines["row"] > test["row"].iloc[1])].iloc[0]
    assert later["time"] < test["time"].iloc[1]


def test_stops_give_the_same_readings_despite_the_resolver_test(run):
    """Without test numbers: the last approach's hold ends in ecmc's resolver test (the axis
    moves 0.8 mm with the set point held); the first settled window is read, not the move."""
    _, log, truth = run
    readings = read_camonitor_readings(log, reference_scale=GEAR)
    assert len(readings) == 90
    both = readings.merge(truth_frame(NINE, truth), on=["target", "direction", "cycle"])
    assert np.abs(both["measured"] - both["measured_true"]).max() < 1e-8
    with_numbers = read_camonitor_readings(run[0], reference_scale=GEAR)
    assert np.allclose(reversal(readings), reversal(with_numbers), atol=1e-6)


def test_iso_and_report_take_the_readers_options(run, tmp_path, capsys):
    log = run[0]
    capsys.readouterr()
    assert main(["iso", str(log), "--reference-scale", "-1.0036,50.3", "--json",
                 "--no-track"]) == 0
    cli = json.loads(capsys.readouterr().out)[0]
    assert cli["B"] == pytest.approx(34.0, abs=0.8)
    with pytest.warns(BacklashWarning):
        python = bl.iso(str(log), reference_scale=GEAR, track=False)
    assert python.to_dict()[0]["B"] == pytest.approx(cli["B"], abs=1e-9)
    out = tmp_path / "report"
    assert main(["report", str(log), "--reference-scale", "-1.0036,50.3", "--out",
                 str(out)]) == 0
    assert (out / "iso_report.html").exists()
    capsys.readouterr()
    line = refused(capsys, ["iso", str(log), "--reference-scale", "0,1"])
    assert "--reference-scale" in line and "SCALE not 0" in line


def test_ten_positions_number_their_tests_with_two_digits(tmp_path):
    """seq -w: with ten positions ecmc numbers 11001 .. 11010 (cycle 1), 21010 .. 21001."""
    targets = {i: 10.0 * i for i in range(1, 11)}
    log = write_run(tmp_path / "ten.log", targets, run_readings(targets, 2, 0.01), PVS,
                    speed=40.0, dwell=1.0, alarms=False)
    text = log.read_text()
    assert "11010" in text and "21001" in text and " 1110 " not in text
    readings = read_camonitor_readings(log, reference_scale=1)
    assert len(readings) == 40
    assert sorted(readings["target"].unique()) == [10.0 * i for i in range(1, 11)]
    assert np.allclose(reversal(readings), -10.0, atol=0.6)


def test_a_negative_scale_on_the_command_line(tmp_path, capsys):
    """ecmc's resolver gear ratio as its report prints it, written as it is."""
    from tests.camonitor_logs import read_dat
    from tests.conftest import ECMC

    targets, readings, pvs = read_dat(ECMC / "psi_sls_stepper_ISO230.dat")
    log = write_run(tmp_path / "raw.log", targets, readings, pvs, scale=-0.0146542635,
                    offset=491650.1380340423)
    out = tmp_path / "r.csv"
    assert main(["convert", str(log), "--reference-scale", "-0.0146542635,491650.1380340423",
                 "--out", str(out)]) == 0
    got = pd.read_csv(out)
    assert np.abs(got["measured"] - [readings[("FWD" if d == "+" else "BWD",
                                               list(targets.values()).index(t) + 1, c)]
                                     for t, d, c in zip(got["target"], got["direction"],
                                                        got["cycle"])]).max() < 1e-6


def settle_log(tmp_path, creep_um_per_s: float):
    """Two targets from both sides, two cycles; at the second forward stop of cycle 2 the
    reference creeps ``creep_um_per_s`` for the whole hold."""
    start = pd.Timestamp("2026-01-05 08:00:00")
    lines, t = [], 0.0

    def line(pv, seconds, value):
        return (f"MC:X-{pv} {start + pd.Timedelta(seconds=seconds):%Y-%m-%d %H:%M:%S.%f} "
                f"{value:.6f}")

    for j in (1, 2):
        for x, sign in ((10.0, -1), (20.0, -1), (20.0, 1), (10.0, 1)):
            lines.append(line("PosSet", t, x + 2 * sign))
            lines.append(line("Enc", t + 0.01, x + 2 * sign))
            t += 1.0
            lines.append(line("PosSet", t, x))
            creep = creep_um_per_s if (j, x, sign) == (2, 20.0, -1) else 0.0
            for k in range(1, 301):  # 3 s at 100 Hz
                drift = creep * 1e-3 * k / 100
                lines.append(line("Enc", t + k / 100, x + 0.002 * sign + drift
                                  + 1e-5 * (-1) ** k))
            t += 3.2
    path = tmp_path / "creep.log"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_hold_where_the_axis_never_settles_is_refused(tmp_path, capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the parking stops, reached one way only
        assert len(read_camonitor_readings(settle_log(tmp_path, 0.0), reference_scale=1)) == 8
    log = settle_log(tmp_path, 40.0)  # 40 um/s: still moving after 3 s
    with pytest.raises(InputError, match=r"the reference never settles .*a reading taken "
                                         "while the axis moves is no measurement"):
        read_camonitor_readings(log, reference_scale=1)
    out = tmp_path / "r.csv"
    capsys.readouterr()
    line = refused(capsys, ["convert", str(log), "--reference-scale", "1", "--out", str(out)])
    assert "never settles" in line and "row" in line and not out.exists()


def test_a_stop_outside_the_run_is_refused_not_guessed(run, tmp_path):
    """An extra stop at a target after the run (a repeat move, a check) makes its count differ:
    without test numbers which stop is not the run's cannot be told."""
    _, log, _ = run
    lines = log.read_text().splitlines()
    last = pd.Timestamp(lines[-1].split()[1] + " " + lines[-1].split()[2])
    when = last + pd.Timedelta(seconds=1)  # a check move to -10 mm, settled for 3 s
    extra = [f"{PVS['TGT_SET_PV']:<30} {when:%Y-%m-%d %H:%M:%S.%f} -10  "]
    reading = (-10.0 - 0.017 - GEAR[1]) / GEAR[0]
    for k in range(1, 300):
        when = last + pd.Timedelta(seconds=1.2 + k / 100)
        extra.append(f"{PVS['REF_PV']:<30} {when:%Y-%m-%d %H:%M:%S.%f} "
                     f"{reading + 1e-6 * (-1) ** k:.8f}  ")
    bad = tmp_path / "extra.log"
    bad.write_text("\n".join(lines + extra) + "\n")
    with pytest.raises(InputError, match=r"target -10 is stopped at 6 times from \+ but the "
                                         r"others 5 times.*give the test channel"):
        read_camonitor_readings(bad, reference_scale=GEAR)


def test_invalid_values_are_dropped_and_counted(tmp_path):
    """The line right before the test number is a dropout: the last valid value is read."""
    path = tmp_path / "invalid.log"
    path.write_text("MC:X-PosSet 2026-01-05 08:00:00.000000 1\n"
                    "MC:X-Enc 2026-01-05 08:00:01.000000 1.001\n"
                    "MC:X-Enc 2026-01-05 08:00:01.010000 33.810 READ INVALID\n"
                    "MC:TestNumber 2026-01-05 08:00:01.100000 1101\n"
                    "MC:X-PosSet 2026-01-05 08:00:02.000000 3\n"
                    "MC:X-PosSet 2026-01-05 08:00:02.500000 1\n"
                    "MC:X-Enc 2026-01-05 08:00:03.000000 0.999\n"
                    "MC:TestNumber 2026-01-05 08:00:03.100000 2101\n")
    with pytest.warns(BacklashWarning, match=r"1 values logged with alarm severity INVALID .*"
                                             r"1 of reference \(MC:X-Enc\)"):
        readings = read_camonitor_readings(path, reference_scale=1)
    assert list(readings["measured"]) == [1.001, 0.999]


def test_poscmd_names_the_set_point_and_posact_the_motor(tmp_path):
    """ecmc's commanded position ``-PosCmd`` is the set point, like ``-PosSet``; ``-PosAct``
    of the same axis is the motor side, not a second reference."""
    pvs = {"REF_PV": "MC:ec0-s5-Enc-PosAct", "TEST_PV": "MC:TestNumber",
           "TGT_SET_PV": "MC:X-PosCmd"}
    targets = {1: 10.0, 2: 20.0}
    log = write_run(tmp_path / "cmd.log", targets, run_readings(targets, 2, 0.006), pvs,
                    speed=20.0, dwell=1.0, alarms=False, test_numbers=False)
    text = log.read_text().splitlines()
    motor = [line.replace("MC:X-PosCmd", "MC:X-PosAct") for line in text
             if line.startswith("MC:X-PosCmd")]
    log.write_text("\n".join(text + motor) + "\n")
    readings = read_camonitor_readings(log, reference_scale=1)
    assert set(readings["axis"]) == {"X"} and set(readings["machine_id"]) == {"MC"}
    assert len(readings) == 8
    assert np.allclose(reversal(readings), -6.0, atol=0.6)


def test_monitor_on_the_run_reports_its_lost_motion_and_refuses_raw_counts(tmp_path, capsys):
    """The same ISO run as a trace: the open-loop counter is the motor side, the laser the load
    side mapped by ecmc's (negative) gear ratio; the run's lost motion is 34 um. A resolver
    logged in raw increments as the load side is refused, never printed as a figure."""
    truth = run_readings(NINE, 5, 0.034, seed=3)
    motor = "IOC_TEST:Axis1-PosAct"
    log = write_run(tmp_path / "run.log", NINE, truth, PVS, scale=GEAR[0], offset=GEAR[1],
                    speed=20.0, dwell=1.5, tail_mm=0.8, motor_pv=motor)
    resolver = "IOC_TEST:ec0-s4-EL7211-Enc-PosAct"  # 2^20 increments per 5 mm
    lines = log.read_text().splitlines()
    counts = []
    for line in lines:
        if line.startswith(motor):
            _, day, clock, value = line.split()
            raw = float(value) * 2**20 / 5 + 491650
            counts.append(f"{resolver:<30} {day} {clock} {raw:.0f}  ")
    log.write_text("\n".join(lines + counts) + "\n")
    channels = f"commanded={PVS['TGT_SET_PV']},motor={motor},load={PVS['REF_PV']}"
    capsys.readouterr()
    assert main(["monitor", str(log), "--log-format", "camonitor", "--channels", channels,
                 "--reference-scale", "-1.0036,50.3", "--axis", "X", "--json"]) == 0
    (axis,) = json.loads(capsys.readouterr().out)["axes"]
    (day,) = axis["days"]
    assert day["lost_motion_um"] == pytest.approx(34.0, abs=2.0)
    iso = read_camonitor_readings(log, {"target": PVS["TGT_SET_PV"], "reference": PVS["REF_PV"],
                                        "test": PVS["TEST_PV"]}, reference_scale=GEAR)
    assert -reversal(iso).min() - 2 <= day["lost_motion_um"] <= -reversal(iso).max() + 2
    line = refused(capsys, ["monitor", str(log), "--log-format", "camonitor", "--channels",
                            channels.replace(PVS["REF_PV"], resolver), "--axis", "X"])
    assert resolver in line and "raw counts" in line
