"""Raw controller logs: EPICS camonitor logs (real ecmc logs and ISO 230-2 runs written in
their exact format from real ecmc ISO230.dat readings), LinuxCNC halsampler/halscope exports,
and every bad input they are refused for."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from features.readings import layouts
from features.readings.approaches import find_stops, read_camonitor_readings
from features.readings.camonitor import parse_camonitor, read_camonitor
from features.readings.errors import BacklashWarning, InputError
from features.readings.formats import read_ecmc
from features.readings.halsampler import read_halsampler
from pipeline.cli import main
from tests.camonitor_logs import read_dat, run_readings, write_run
from tests.conftest import REAL_DATA
from tests.test_cli_errors import refused

LOGS = REAL_DATA / "camonitor"
OPEN_LOOP, RESOLVER = "IOC_TEST:Axis1-PosAct", "IOC_TEST:ec0-s4-EL7211-Enc-PosAct"
needs_logs = pytest.mark.skipif(not LOGS.is_dir(), reason="real camonitor logs not present")


@pytest.fixture(scope="module")
def ess_log(tmp_path_factory, request):
    """The ESS mcu1025 ISO 230-2 run as camonitor logged it: written from its .dat file."""
    from tests.conftest import ECMC

    dat = ECMC / "ess_mcu1025_ISO230.dat"
    path = tmp_path_factory.mktemp("logs") / "data.log"
    return write_run(path, *read_dat(dat)), dat


def channels(dat) -> str:
    pvs = read_dat(dat)[2]
    return (f"target={pvs['TGT_SET_PV']},reference={pvs['REF_PV']},test={pvs['TEST_PV']}")


def reversal(readings: pd.DataFrame) -> pd.Series:
    """B_i = mean_up - mean_down per target [um], computed here (not by the product)."""
    mean = readings.groupby(["target", "direction"])["deviation_um"].mean().unstack()
    return (mean["+"] - mean["-"]).round(9)


# ------------------------------------------------------------------ the real logs


@needs_logs
def test_every_real_log_parses_line_for_line():
    expected = {"bifrost_11358_axis1_repeat_pos20.log": {OPEN_LOOP: 4467, RESOLVER: 18523},
                "bifrost_11358_axis1_resolver_openloop.log": {OPEN_LOOP: 4303, RESOLVER: 4303},
                "bifrost_11358_axis1_standstill_x0deg.log": {OPEN_LOOP: 1, RESOLVER: 636}}
    for name, counts in expected.items():
        lines = parse_camonitor(LOGS / name)
        assert lines["pv"].value_counts().to_dict() == counts
        assert (lines["row"] == np.arange(1, len(lines) + 1)).all()
        assert str(lines["time"].dt.tz) == "UTC" and lines["value"].notna().all()
        assert (lines["status"] == "").all()  # the real logs hold no alarms
    first = parse_camonitor(LOGS / "bifrost_11358_axis1_repeat_pos20.log").iloc[1]
    assert first["pv"] == OPEN_LOOP and first["value"] == 19.49976563
    assert first["time"] == pd.Timestamp("2020-12-09 15:05:40.306118", tz="UTC")


@needs_logs
def test_open_loop_and_resolver_series_of_one_move():
    samples = read_camonitor(LOGS / "bifrost_11358_axis1_resolver_openloop.log",
                             {"motor": OPEN_LOOP, "load": RESOLVER})
    assert len(samples) == 8605  # every line but the one before both PVs have a value
    assert samples["time"].is_monotonic_increasing
    seconds = (samples["time"] - samples["time"].iloc[0]).dt.total_seconds()
    speed = np.polyfit(seconds, samples["motor"], 1)[0]
    assert speed == pytest.approx(0.25, rel=1e-3)  # README: constant speed, 0.9 -> 11.7 mm
    gear = np.polyfit(samples["motor"], samples["load"], 1)[0]
    assert gear == pytest.approx(1.0, abs=1e-3)


@needs_logs
def test_standstill_log_keeps_the_connection_value_of_the_quiet_pv():
    samples = read_camonitor(LOGS / "bifrost_11358_axis1_standstill_x0deg.log",
                             {"motor": OPEN_LOOP, "load": RESOLVER})
    # the open-loop counter is logged once, 20 s before the log starts: every row holds it
    assert len(samples) == 636 and (samples["motor"] == -7.8125e-05).all()
    assert samples["load"].std() * 1000 < 0.05  # resolver noise at rest [um]


@needs_logs
def test_stops_of_the_real_repeat_log():
    samples = read_camonitor(LOGS / "bifrost_11358_axis1_repeat_pos20.log",
                             {"target": OPEN_LOOP, "reference": RESOLVER})
    stops = find_stops(samples, dwell_s=1.0)
    # README: repeated moves between 19.5 and 20.0 mm; the log starts at rest at 19.5
    assert len(stops) == 20
    assert list(stops["direction"]) == ["+", "-"] * 10
    assert np.allclose(stops["target"], np.tile([20.000234, 19.499766], 10))
    travel = stops["reference"].diff().abs().iloc[1:]
    assert travel.between(0.499, 0.501).all()
    # each position is reached from one side only: no ISO 230-2 target
    with pytest.raises(InputError, match="from both directions"):
        read_camonitor_readings(LOGS / "bifrost_11358_axis1_repeat_pos20.log",
                                {"target": OPEN_LOOP, "reference": RESOLVER}, 1.0)


# ------------------------------------------------------------------ ISO 230-2 runs


def test_ess_run_converts_to_its_dat_readings(ess_log, tmp_path, capsys):
    log, dat = ess_log
    out = tmp_path / "r.csv"
    assert main(["convert", str(log), "--format", "camonitor", "--channels", channels(dat),
                 "--reference-scale", "1", "--out", str(out)]) == 0
    readings = pd.read_csv(out)
    assert len(readings) == 50
    assert set(readings["machine_id"]) == {"IOC_TEST:Axis1"}
    assert readings["test_id"].str.startswith("Axis1-").all()
    truth = read_ecmc(dat).merge(readings, on=["target", "direction", "cycle"],
                                 suffixes=("_dat", ""))
    assert len(truth) == 50
    assert np.abs(truth["measured"] - truth["measured_dat"]).max() < 1e-9
    assert (readings["method"] == "linear").all()
    capsys.readouterr()
    figures = []
    for source in (out, dat):  # the same ISO 230-2 figures as the .dat file's
        assert main(["iso", str(source), "--json"]) == 0
        figures.append(json.loads(capsys.readouterr().out)[0])
    for name in ("A", "E", "M", "R", "B", "B_mean"):
        assert figures[0][name] == pytest.approx(figures[1][name], abs=1e-6)


def test_fitted_gear_ratio_keeps_reversal_values_within_tolerance(ess_log, tmp_path, capsys):
    log, dat = ess_log
    out = tmp_path / "r.csv"
    assert main(["convert", str(log), "--format", "camonitor", "--channels", channels(dat),
                 "--out", str(out)]) == 0
    assert "fitted gear ratio" in capsys.readouterr().err
    got, want = reversal(pd.read_csv(out)), reversal(read_ecmc(dat))
    assert len(got) == 5
    assert (np.abs(got - want) <= np.maximum(0.3, 0.02 * np.abs(want))).all()


def test_raw_encoder_counts_without_test_numbers(tmp_path):
    """The reference in raw units (a resolver's gear ratio and offset from ecmc's report) and
    no test-number PV: approaches are the stops, the ratio is fitted back."""
    from tests.conftest import ECMC

    targets, readings, pvs = read_dat(ECMC / "psi_sls_stepper_ISO230.dat")
    ratio, offset = -0.0146542635, 491650.1380340423
    log = write_run(tmp_path / "raw.log", targets, readings, pvs, scale=ratio, offset=offset,
                    test_numbers=False)
    with pytest.warns(BacklashWarning, match=r"gear ratio -0\.01465"):
        fitted = read_camonitor_readings(log)  # channels inferred from ecmc's PV names
    given = read_camonitor_readings(log, reference_scale=(ratio, offset))
    dat = read_ecmc(ECMC / "psi_sls_stepper_ISO230.dat")
    truth = dat.merge(given, on=["target", "direction", "cycle"], suffixes=("_dat", ""))
    assert len(given) == len(truth) == 50
    assert np.abs(truth["measured"] - truth["measured_dat"]).max() < 1e-6
    assert (np.abs(reversal(fitted) - reversal(dat)) <= np.maximum(0.3, 0.02 * np.abs(
        reversal(dat)))).all()
    assert set(given["machine_id"]) == {"sls-sioc-ecat01:M1"}


def test_ninety_approaches_of_an_axis_with_known_lost_motion(tmp_path, capsys):
    """Nine targets, five cycles: 90 approaches; an axis losing 8 um at each reversal reads
    B_i = -8 um at every target (noise 0.2 um)."""
    targets = {i: 10.0 + 25.0 * (i - 1) for i in range(1, 10)}
    pvs = {"REF_PV": "MC:X-Enc01-PosAct", "TEST_PV": "MC:TestNumber", "TGT_SET_PV": "MC:X-PosSet"}
    log = write_run(tmp_path / "x.log", targets, run_readings(targets, 5, 0.008), pvs,
                    speed=50.0, dwell=1.5, alarms=False)
    out = tmp_path / "x.csv"
    assert main(["convert", str(log), "--reference-scale", "1", "--out", str(out)]) == 0
    readings = pd.read_csv(out)
    assert len(readings) == 90 and set(readings["axis"]) == {"X"}
    assert set(readings["machine_id"]) == {"MC"}
    assert np.allclose(reversal(readings), -8.0, atol=0.6)
    capsys.readouterr()
    assert main(["iso", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)[0]
    assert figures["B"] == pytest.approx(8.0, abs=0.6)
    assert figures["B_mean"] == pytest.approx(-8.0, abs=0.3)


def test_other_jobs_read_the_log_directly(ess_log, capsys):
    log, _ = ess_log
    assert layouts.detect_format(log) == "camonitor"
    assert main(["iso", str(log)]) == 0  # channels inferred, gear ratio fitted
    err = capsys.readouterr().err
    assert "fitted gear ratio" in err


def test_connection_lines_are_left_out_with_a_note(tmp_path):
    path = tmp_path / "c.log"
    path.write_text("MC:X-Enc *** disconnected\n"
                    "MC:X-Enc 2026-01-05 08:00:00.000000 1.5\n"
                    "MC:X-Set <undefined> <undefined> UDF INVALID\n"
                    "MC:X-Enc 2026-01-05 08:00:00.010000 1.6 HIHI MAJOR\n")
    with pytest.warns(BacklashWarning, match="2 lines"):
        lines = parse_camonitor(path)
    assert list(lines["row"]) == [2, 4] and list(lines["value"]) == [1.5, 1.6]
    assert list(lines["status"]) == ["", "HIHI"] and list(lines["severity"]) == ["", "MAJOR"]


def pendulum_log(path, axis_pv: str = "MC:Y", scale: float = 1.0):
    """Two targets (10, 20 x ``scale``), two cycles, every approach after a reversal; forward
    readings 2 x ``scale`` / 1000 short, backward as long: B_i = -4 x ``scale`` / 1000."""
    start = pd.Timestamp("2026-01-05 08:00:00")

    def line(pv, seconds, value, alarm=""):
        when = start + pd.Timedelta(seconds=seconds)
        return f"{pv} {when:%Y-%m-%d %H:%M:%S.%f} {value} {alarm}"

    lines, t = [], 0.0
    for j in (1, 2):
        for i, x in ((1, 10.0 * scale), (2, 20.0 * scale)):
            for d, sign in ((1, -1), (2, 1)):
                t += 5  # move past the target, come back, settle; then ecmc sets the number
                lines += [line(f"{axis_pv}-PosSet", t, x + sign * scale),
                          line(f"{axis_pv}-PosSet", t + 1, x),
                          line(f"{axis_pv}-Enc", t + 3, x + sign * 0.002 * scale, "HIGH MINOR"),
                          line("MC:TestNumber", t + 4, d * 1000 + j * 100 + i)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_pendulum_order_and_letter_axis(tmp_path):
    """Every approach right after a reversal: a pendulum test; PV MC:Y-... names axis Y."""
    readings = read_camonitor_readings(pendulum_log(tmp_path / "p.log"), reference_scale=1)
    assert set(readings["method"]) == {"pendulum"} and set(readings["axis"]) == {"Y"}
    assert set(readings["machine_id"]) == {"MC"}
    assert np.allclose(reversal(readings), -4.0)


def test_set_point_units(tmp_path, capsys):
    rotary = read_camonitor_readings(pendulum_log(tmp_path / "b.log", "MC:B"), reference_scale=1)
    assert set(rotary["axis"]) == {"B"}  # deg: deviations in arcsec
    assert np.allclose(reversal(rotary), -0.004 * 3600)
    um = pendulum_log(tmp_path / "um.log", "IOC:Axis2", scale=1000.0)
    out = tmp_path / "um.csv"
    assert main(["convert", str(um), "--unit", "um", "--reference-scale", "1", "--out",
                 str(out)]) == 0
    readings = pd.read_csv(out)
    assert sorted(set(readings["target"])) == [10.0, 20.0]  # mm
    assert np.allclose(reversal(readings), -4.0)
    assert set(readings["machine_id"]) == {"IOC:Axis2"} and set(readings["axis"]) == {"X"}
    capsys.readouterr()
    line = refused(capsys, ["convert", str(tmp_path / "b.log"), "--unit", "mm", "--out",
                            str(tmp_path / "x.csv")])
    assert "b.log, --unit: unit mm but the set-point PV names axis B; expected deg" in line
    line = refused(capsys, ["convert", str(um), "--unit", "inch", "--out", str(out)])
    assert "--unit" in line and "invalid choice" in line
    with pytest.raises(InputError, match="unknown unit 'inch'; expected mm, um or deg"):
        read_camonitor_readings(um, unit="inch")


# ------------------------------------------------------------------ bad inputs


def _log(tmp_path, text: str):
    path = tmp_path / "bad.log"
    path.write_text(text)
    return path


GOOD = ("MC:X-PosSet 2026-01-05 08:00:00.000000 1\n"
        "MC:X-Enc 2026-01-05 08:00:01.000000 1.001\n"
        "MC:TestNumber 2026-01-05 08:00:01.100000 1101\n")
CHANNELS = "target=MC:X-PosSet,reference=MC:X-Enc,test=MC:TestNumber"


@pytest.mark.parametrize("text, channels, expected", [
    (GOOD + "MC:X-Enc 2026-01-05 07:59:59.000000 1.002\n", CHANNELS,
     "row 4: time goes back for PV MC:X-Enc"),
    ("MC:X-PosSet 2026-01-05 08:00:00.000000 1\n" + GOOD.split("\n", 1)[1].replace(
        "MC:X-Enc", "MC:Y-Enc"), CHANNELS, "is never logged"),
    (GOOD, "target=MC:X-PosSet,test=MC:TestNumber", "channel 'reference' is missing"),
    (GOOD, CHANNELS + ",speed=MC:X-Vel", "unknown channel 'speed'"),
    (GOOD, "target=MC:X-PosSet,reference=MC:X-Scale,test=MC:TestNumber",
     "PV 'MC:X-Scale' (channel reference) is never logged"),
    (GOOD, "target=MC:X-PosSet,reference", "'reference' is not name=PV"),
    (GOOD + "MC:X-Enc 2026-01-05 08:00:02.000000 moving to the target\n", CHANNELS,
     "row 4: expected 'PV date time value [status severity]'"),
    (GOOD + "MC:X-Enc 05.01.2026 08:00:02 1.0\n", CHANNELS, "row 4: 'MC:X-Enc 05.01.2026"),
    (GOOD + "MC:X-Enc 2026-01-05 08:00:02.000000 n/a\n", CHANNELS,
     "row 4: PV MC:X-Enc (channel reference) logs 'n/a'; expected a finite number"),
    (GOOD + "MC:TestNumber 2026-01-05 08:00:03.000000 0\n"
     "MC:TestNumber 2026-01-05 08:00:04.000000 1101\n", CHANNELS, "test number 1101 is set twice"),
    (("MC:X-PosSet 2026-01-05 08:00:00.000000 1\n"
      "MC:TestNumber 2026-01-05 08:00:00.100000 1101\n"
      "MC:X-Enc 2026-01-05 08:00:01.000000 1.001\n"), CHANNELS,
     "row 2: test number 1101 is set before the set point and the reference are logged"),
    (GOOD.replace("1101", "7"), CHANNELS, "no ISO 230-2 test numbers"),
    ("", CHANNELS, "no value lines"),
])
def test_bad_logs_are_one_line_and_write_nothing(tmp_path, capsys, text, channels, expected):
    out = tmp_path / "r.csv"
    line = refused(capsys, ["convert", str(_log(tmp_path, text)), "--format", "camonitor",
                              "--channels", channels, "--out", str(out)])
    assert expected in line, line
    assert not out.exists()


def test_bad_options_are_one_line(tmp_path, capsys, ess_file):
    out = tmp_path / "r.csv"
    line = refused(capsys, ["convert", str(_log(tmp_path, GOOD)), "--format", "camonitor",
                              "--channels", CHANNELS, "--reference-scale", "0", "--out",
                              str(out)])
    assert "--reference-scale" in line and "SCALE not 0" in line
    line = refused(capsys, ["convert", str(ess_file), "--channels", CHANNELS, "--out",
                              str(out)])
    assert "--channels" in line and "camonitor files only" in line
    line = refused(capsys, ["convert", str(_log(tmp_path, GOOD.replace("PosSet", "Cmd"))),
                              "--out", str(out)])
    assert "cannot tell which PV is which" in line and "--channels" in line
    assert not out.exists()


# ------------------------------------------------------------------ LinuxCNC


def test_halsampler_output_with_sample_numbers(tmp_path):
    path = tmp_path / "hs.txt"
    path.write_text("10 0.0 0.001 \n11 0.5 0.499\n13 1.5 1.497\n")
    samples = read_halsampler(path, {"sample": 0, "commanded": 1, "motor": 2}, period_s=0.001,
                              start="2026-01-05T08:00:00")
    assert list(samples.columns) == ["time", "commanded", "motor", "row"]
    assert list((samples["time"] - samples["time"].iloc[0]).dt.total_seconds()) == [
        0.0, 0.001, 0.003]  # a lost sample (12) keeps its time
    assert list(samples["motor"]) == [0.001, 0.499, 1.497]


def test_halscope_exports_both_layouts(tmp_path):
    new = tmp_path / "scope.csv"
    new.write_text("# Sampling period is 1000000 ns\njoint.0.pos-cmd;joint.0.pos-fb\n"
                   "# Position: 0.5;0.5\n# Scale: 0;0\n1.00000000000000;0.90000000000000\n"
                   "1.10000000000000;1.00000000000000\n")
    old = tmp_path / "scope.log"
    old.write_text("Sampling period is 1000000 nSec \n\njoint.0.pos-cmd +1.00000000000000 "
                   "joint.0.pos-fb +0.90000000000000 \njoint.0.pos-cmd +1.10000000000000 "
                   "joint.0.pos-fb +1.00000000000000 \n")
    pins = {"commanded": "joint.0.pos-cmd", "motor": "joint.0.pos-fb"}
    for path in (new, old):
        samples = read_halsampler(path, pins, start="2026-01-05T08:00:00+01:00")
        assert samples["time"].iloc[1] == pd.Timestamp("2026-01-05 07:00:00.001", tz="UTC")
        assert list(samples["commanded"]) == [1.0, 1.1] and list(samples["motor"]) == [0.9, 1.0]
    with pytest.warns(BacklashWarning, match="modification time"):
        read_halsampler(old, pins)


@pytest.mark.parametrize("text, columns, period, expected", [
    ("0 1.0\n1 x\n", {"motor": 1}, 0.001, "row 2, column '1': 'x' is not a finite number"),
    ("0 1.0\n1 2.0 3.0\n", {"motor": 1}, 0.001, "row 2: a line has 3 fields"),
    ("0 1.0\n1 2.0\n", {"motor": 2}, 0.001, "channel motor is field 2, but lines have 2"),
    ("0 1.0\n1 2.0\n", {"motor": 1}, None, "halsampler writes no sample period"),
    ("5 1.0\n4 2.0\n", {"sample": 0, "motor": 1}, 0.001, "row 2: sample number 4 after 5"),
    ("# Sampling period is 1000 ns\na;b\n1;2\n", {"motor": "c"}, None,
     "channel motor is pin 'c', which the file does not log"),
])
def test_bad_linuxcnc_files(tmp_path, text, columns, period, expected):
    path = tmp_path / "hs.txt"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        read_halsampler(path, columns, period_s=period, start="2026-01-05")
    assert expected in err.value.line()
