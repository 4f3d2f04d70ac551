"""``monitor --log-format camonitor|halsampler``: lost motion from a controller's raw log, checked
on camonitor logs written from an independent generator's known trace
(tests/independent_traces.py), on a real ecmc log, and every bad input refused."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.workflows.monitor import monitor
from tests.camonitor_logs import write_trace_log
from tests.conftest import REAL_DATA
from tests.independent_traces import axis_day
from tests.test_cli_errors import refused

SET, MOTOR, SCALE = "MC:X-PosSet", "MC:X-PosAct", "MC:ec0-s4-EL5101-Enc-PosAct"
CHANNELS = f"commanded={SET},motor={MOTOR},load={SCALE}"
LOGS = REAL_DATA / "camonitor"
OPEN_LOOP, RESOLVER = "IOC_TEST:Axis1-PosAct", "IOC_TEST:ec0-s4-EL7211-Enc-PosAct"
needs_logs = pytest.mark.skipif(not LOGS.is_dir(), reason="real camonitor logs not present")


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """A minute of an axis with 6 um of play at 100 Hz, logged as camonitor logs it."""
    t, cmd, motor, load = axis_day(np.random.default_rng(0), 6.0, seconds=60, rate_hz=100)
    path = tmp_path_factory.mktemp("logs") / "x.log"
    return write_trace_log(path, t, {SET: cmd, MOTOR: motor, SCALE: load})


def test_lost_motion_of_a_camonitor_log_within_its_uncertainty(log):
    result = monitor(log, format="camonitor", channels=CHANNELS)
    (day,) = result.daily.itertuples()
    # machine and axis from the set point's name: IOC prefix MC, axis letter X
    assert (day.machine_id, day.axis, day.date) == ("MC", "X", "2021-11-10")
    assert day.reversals >= 4
    assert 0 < day.lost_motion_u_um < 0.05
    assert abs(day.lost_motion_um - 6.0) < 3 * day.lost_motion_u_um


def test_cli_reads_a_log_and_options_name_machine_and_axis(log, capsys):
    code = main(["monitor", str(log), "--log-format", "camonitor", "--channels", CHANNELS,
                 "--machine", "M9", "--axis", "y", "--json"])
    assert code == 0
    (axis,) = json.loads(capsys.readouterr().out)["axes"]
    assert (axis["machine_id"], axis["axis"]) == ("M9", "Y")
    assert axis["days"][0]["lost_motion_um"] == pytest.approx(6.0, abs=0.02)


def test_halsampler_output_gives_the_same_lost_motion(tmp_path):
    t, cmd, motor, load = axis_day(np.random.default_rng(0), 6.0, seconds=60, rate_hz=100)
    path = tmp_path / "x.txt"
    np.savetxt(path, np.c_[np.arange(len(t)), cmd, motor, load], fmt="%.6f")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file states no clock time: a note
        result = monitor(path, format="halsampler", channels="sample=0,commanded=1,motor=2,"
                         "load=3", period_s=0.01, machine="M1", axis="X")
    (day,) = result.daily.itertuples()
    assert abs(day.lost_motion_um - 6.0) < 3 * day.lost_motion_u_um


@pytest.mark.parametrize("options, expected", [
    (["--channels", f"commanded={SET},load={SCALE}"], "--channels: channel 'motor' is missing"),
    (["--channels", f"commanded={SET},motor={MOTOR}"],
     "--channels: lost motion needs a load-side position"),
    (["--channels", f"commanded={SET},motor={MOTOR},load=MC:Z-PosAct"],
     "PV 'MC:Z-PosAct' (channel load) is never logged"),
    (["--channels", f"commanded={SET},motor={MOTOR},load={SCALE},spindle=MC:S"],
     "--channels: unknown channel 'spindle'"),
    ([], "--channels: a camonitor log needs its channels"),
    (["--channels", CHANNELS, "--axis", "Q"], "--axis: unknown axis 'Q'"),
])
def test_bad_channels_are_refused(log, capsys, options, expected):
    line = refused(capsys, ["monitor", str(log), "--log-format", "camonitor", *options])
    assert expected in line


def test_an_unnamed_axis_needs_the_option(tmp_path, capsys):
    t, cmd, motor, load = axis_day(np.random.default_rng(1), 6.0, seconds=5, rate_hz=100)
    path = write_trace_log(tmp_path / "a.log", t, {"IOC:Axis1-PosSet": cmd,
                                                   "IOC:Axis1-PosAct": motor, SCALE: load})
    line = refused(capsys, ["monitor", str(path), "--log-format", "camonitor", "--channels",
                            f"commanded=IOC:Axis1-PosSet,motor=IOC:Axis1-PosAct,load={SCALE}"])
    assert "--axis: the log's channel names state no axis" in line


def test_channels_on_a_trace_table_are_refused(tmp_path, capsys):
    path = tmp_path / "trace.csv"
    path.write_text("time,machine_id,axis,commanded_mm,motor_mm,load_mm\n")
    line = refused(capsys, ["monitor", str(path), "--channels", CHANNELS])
    assert "--channels: applies to a raw log" in line


@needs_logs
def test_real_ecmc_log_step_counter_against_resolver():
    """Both PVs are motor-side on this axis: the open-loop step counter as commanded and
    motor position, the resolver as the second position. Eight reversals between 19.5 and
    20.0 mm, all at the stepper's one speed with rests only at the two ends: the estimator
    cannot tell play from servo lag there and gives the day without a value, with a note."""
    channels = {"commanded": OPEN_LOOP, "motor": OPEN_LOOP, "load": RESOLVER}
    with pytest.warns(Warning, match="no lost motion"):
        result = monitor(LOGS / "bifrost_11358_axis1_repeat_pos20.log", format="camonitor",
                         channels=channels, axis="X")
    (day,) = result.daily.itertuples()
    assert (day.machine_id, day.axis, day.date) == ("IOC_TEST", "X", "2020-12-09")
    assert day.reversals == 8 and np.isnan(day.lost_motion_um)
