"""``monitor`` refuses what cannot be physical, on hand-made traces of known truth
(tests/independent_traces.py: an axis with 6 um of play) and on the real ecmc logs: a load
side counting the other way, in raw counts or another unit, a lost motion larger than the
travel or negative beyond its uncertainty, a sample given twice with other values, a Dask
scheduler that never answers, ``--channels`` written with another separator. Each refusal is
one line with exit 2, and nothing is written to ``--out`` or recorded in ``--store``;
``--reference-scale`` gives the load side's scale instead."""

from __future__ import annotations

import json
import socket
import threading
import time
import warnings

import numpy as np
import pandas as pd
import pytest
from store_files import visits

import backlash as bl
from features.readings.errors import InputError
from pipeline.cli import main
from pipeline.workflows.monitor import monitor
from tests.camonitor_logs import write_trace_log
from tests.conftest import REAL_DATA
from tests.independent_traces import axis_day
from tests.test_cli_errors import refused

PLAY_UM = 6.0
COUNTS_PER_MM = 2**20 / 5  # a resolver's 2^20 increments per 5 mm revolution
SET, MOTOR, SCALE = "MC:X-PosSet", "MC:X-PosAct", "MC:ec0-s4-EL5101-Enc-PosAct"
CHANNELS = f"commanded={SET},motor={MOTOR},load={SCALE}"
LOGS = REAL_DATA / "camonitor"
REPEAT = LOGS / "bifrost_11358_axis1_repeat_pos20.log"
OPEN_LOOP, RESOLVER = "IOC_TEST:Axis1-PosAct", "IOC_TEST:ec0-s4-EL7211-Enc-PosAct"
REAL_CHANNELS = f"commanded={OPEN_LOOP},motor={OPEN_LOOP},load={RESOLVER}"
needs_logs = pytest.mark.skipif(not REPEAT.is_file(), reason="real camonitor logs not present")


@pytest.fixture(scope="module")
def day():
    """Half a minute of M1 X at 100 Hz with 6 um of play: (t_s, commanded, motor, load)."""
    return axis_day(np.random.default_rng(4), PLAY_UM, seconds=30, rate_hz=100)


def trace(day, motor=None, load=None) -> pd.DataFrame:
    t, cmd, m, l = day
    return pd.DataFrame({"time": pd.Timestamp("2026-03-02 09:00", tz="UTC")
                         + pd.to_timedelta(t, unit="s"), "machine_id": "M1", "axis": "X",
                         "commanded_mm": cmd, "motor_mm": m if motor is None else motor,
                         "load_mm": l if load is None else load})


def csv(tmp_path, frame, name="trace.csv"):
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return str(path)


def lost_motion(capsys) -> float:
    """The one day's lost motion ``--json`` printed."""
    (axis,) = json.loads(capsys.readouterr().out)["axes"]
    return axis["days"][0]["lost_motion_um"]


def quiet(**kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return monitor(**kwargs)


# ------------------------------------------------------------------- the truth passes
def test_the_true_trace_passes_with_its_play(day):
    (row,) = quiet(traces=trace(day)).daily.itertuples()
    assert abs(row.lost_motion_um - PLAY_UM) < 3 * row.lost_motion_u_um


def test_no_play_is_not_refused_for_its_noise():
    """An axis without play estimates about 0, as often below as above: this day's estimate
    is below zero (within its k = 2 interval), noise all the same."""
    (row,) = quiet(traces=trace(axis_day(np.random.default_rng(2), 0.0, seconds=60,
                                         rate_hz=100))).daily.itertuples()
    assert -2 * row.lost_motion_u_um < row.lost_motion_um < 0


# ------------------------------------------------------------- impossible figures
def test_load_in_raw_counts_is_refused_by_the_travel_ratio(day, tmp_path, capsys):
    path = csv(tmp_path, trace(day, load=day[3] * COUNTS_PER_MM))
    line = refused(capsys, ["monitor", path, "--out", str(tmp_path / "out")])
    assert path in line and "M1 X on 2026-03-02" in line and "load side load_mm" in line
    assert "raw counts" in line and "within a factor of 2" in line
    assert not (tmp_path / "out").exists()


def test_load_in_um_is_named_a_wrong_unit(day):
    with pytest.raises(InputError, match=r"a wrong unit \(um against mm\)"):
        monitor(trace(day, load=day[3] * 1000))


def test_load_counting_the_other_way_is_refused_as_a_sign(day):
    with pytest.raises(InputError, match="load side load_mm moves against the motor side "
                                         "motor_mm .*a sign"):
        monitor(trace(day, load=50.0 - day[3]))


def test_motor_in_counts_is_refused_against_the_set_point(day):
    """A drive logging its encoder in increments: refused before any fit (a spline over
    millions of 'mm' would not fit in memory)."""
    with pytest.raises(InputError, match=r"M1 X on 2026-03-02: the motor side motor_mm travels "
                                         r"3\.1\d+e\+07 mm while the commanded commanded_mm "
                                         r"travels 152\.1\d* mm .*raw counts"):
        monitor(trace(day, motor=day[2] * COUNTS_PER_MM))


def test_every_side_in_counts_is_refused_before_its_statistics_grow(day):
    """Set point, motor and load all in increments agree with each other, so no ratio rule
    fires: the lead-error grid would need millions of control points (gigabytes); refused."""
    t, cmd, m, load = day
    counts = trace((t, cmd * COUNTS_PER_MM, m * COUNTS_PER_MM, load * COUNTS_PER_MM))
    with pytest.raises(InputError, match=r"positions span .* mm in one day.*counts or a wrong "
                                         "unit"):
        quiet(traces=counts)


def test_lost_motion_larger_than_the_travel_is_refused():
    """500 mm of lost motion on 180 mm of travel, the channels' travels alike (what a fit
    gives from channels that agree with each other but not with the axis)."""
    from models.condition.lost_motion import check_physical

    daily = pd.DataFrame([{"machine_id": "M1", "axis": "Y", "unit": "um", "date": "2026-03-02",
                           "lost_motion_um": 500_000.0, "lost_motion_u_um": 900.0,
                           "travel_mm": 180.0, "motor_travel_mm": 180.0,
                           "load_travel_mm": 178.0, "load_gain": 0.99, "load_offset_mm": 0.0}])
    names = {"commanded": "M1:Y-PosSet", "motor": "M1:Y-PosAct", "load": "M1:Y-Scale"}
    with pytest.raises(InputError, match=r"f.log: M1 Y on 2026-03-02: lost motion 500000 um is "
                                         "larger than the day's travel of 180 mm \\(commanded "
                                         "M1:Y-PosSet\\): a wrong scale or unit of the load side "
                                         "M1:Y-Scale or the motor side M1:Y-PosAct; fix"):
        check_physical(daily, names, file="f.log", remedy="; fix")
    check_physical(daily.assign(lost_motion_um=170_000.0), names)  # within the travel


def test_negative_lost_motion_is_refused_naming_the_channels(day, tmp_path, capsys):
    """Motor and load swapped: the load leads the motor by the play at every reversal."""
    path = csv(tmp_path, trace(day, motor=day[3], load=day[2]))
    line = refused(capsys, ["monitor", path])
    assert "lost motion -6.0" in line and "negative beyond its uncertainty" in line
    assert "motor side motor_mm and the load side load_mm swapped" in line


def test_a_refused_run_records_nothing_in_the_store(day, tmp_path, capsys):
    store = tmp_path / "fleet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the new store's note
        bl.ingest(visits(tmp_path, which=("01",)), store=store)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bl.monitor(traces=trace(day), store=store)  # one good day recorded first
    capsys.readouterr()

    def content():
        return {p: p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}

    before = content()
    bad = trace(day, load=day[3] * COUNTS_PER_MM)
    bad["time"] += pd.Timedelta(days=1)  # a new day: it would be added
    refused(capsys, ["monitor", csv(tmp_path, bad), "--store", str(store)])
    assert content() == before


# ------------------------------------------------------------------- a raw log's scale
@pytest.fixture(scope="module")
def counts_log(day, tmp_path_factory):
    """The day as camonitor logs it, the scale in raw counts with its own zero."""
    t, cmd, motor, load = day
    path = tmp_path_factory.mktemp("logs") / "counts.log"
    return write_trace_log(path, t, {SET: cmd, MOTOR: motor,
                                     SCALE: (load - 120.0) * COUNTS_PER_MM}, digits=3)


def test_a_log_in_counts_is_refused_naming_its_pv(counts_log, capsys):
    line = refused(capsys, ["monitor", str(counts_log), "--log-format", "camonitor",
                            "--channels", CHANNELS])
    assert str(counts_log) in line and "MC X on 2021-11-10" in line
    assert f"load side {SCALE} travels" in line and "raw counts" in line
    assert "--reference-scale GAIN,OFFSET" in line


def test_reference_scale_gives_the_load_in_mm(counts_log, capsys):
    gain = 1 / COUNTS_PER_MM
    assert main(["monitor", str(counts_log), "--log-format", "camonitor", "--channels",
                 CHANNELS, f"--reference-scale={gain!r},120", "--json"]) == 0
    result = quiet(traces=counts_log, format="camonitor", channels=CHANNELS,
                   reference_scale=(gain, 120.0))
    (row,) = result.daily.itertuples()
    assert abs(row.lost_motion_um - PLAY_UM) < 3 * row.lost_motion_u_um
    assert f'"lost_motion_um": {round(row.lost_motion_um, 4)}' in capsys.readouterr().out


@pytest.fixture(scope="module")
def mirrored_log(day, tmp_path_factory):
    """An external reference counting the other way: -(load) + 50.3 logged."""
    t, cmd, motor, load = day
    path = tmp_path_factory.mktemp("logs") / "mirrored.log"
    return write_trace_log(path, t, {SET: cmd, MOTOR: motor, SCALE: 50.3 - load})


def test_a_reference_counting_the_other_way_needs_a_negative_gain(mirrored_log, capsys):
    line = refused(capsys, ["monitor", str(mirrored_log), "--log-format", "camonitor",
                            "--channels", CHANNELS])
    assert "moves against the motor side" in line and "a sign" in line
    assert main(["monitor", str(mirrored_log), "--log-format", "camonitor", "--channels",
                 CHANNELS, "--reference-scale=-1,50.3", "--json"]) == 0
    assert abs(lost_motion(capsys) - PLAY_UM) < 0.05


def test_a_negative_gain_given_after_a_space(mirrored_log, capsys):
    """``--reference-scale -1,50.3``: the command line's negative values (pipeline/cli.py)."""
    assert main(["monitor", str(mirrored_log), "--log-format", "camonitor", "--channels",
                 CHANNELS, "--reference-scale", "-1,50.3", "--json"]) == 0
    assert abs(lost_motion(capsys) - PLAY_UM) < 0.05


@pytest.mark.parametrize("scale, expected", [
    ((0.0, 1.0), "gain not 0"), ((1.0, float("nan")), "finite numbers"),
    ((1.0, 2.0, 3.0), "expected GAIN or"),
])
def test_a_bad_reference_scale_is_refused(counts_log, scale, expected):
    with pytest.raises(InputError, match=expected) as caught:
        monitor(counts_log, format="camonitor", channels=CHANNELS, reference_scale=scale)
    assert caught.value.parameter == "reference_scale"


def test_reference_scale_on_a_trace_table_is_refused(day, tmp_path, capsys):
    line = refused(capsys, ["monitor", csv(tmp_path, trace(day)), "--reference-scale", "2"])
    assert "--reference-scale: applies to a raw log (--log-format camonitor" in line


def test_an_offset_load_side_is_said_and_changes_nothing(day):
    plain = quiet(traces=trace(day)).daily
    with pytest.warns(Warning, match=r"M1 X: the load side load_mm sits \+420\.\d+ mm from the "
                                     "motor side motor_mm"):
        shifted = monitor(trace(day, load=day[3] + 420.0)).daily
    assert shifted.lost_motion_um.iloc[0] == pytest.approx(plain.lost_motion_um.iloc[0],
                                                           abs=1e-6)


# ------------------------------------------------------------------------ real logs
@needs_logs
def test_real_resolver_in_counts_is_refused(tmp_path, capsys):
    """The real resolver's values scaled to 2^20 counts per 5 mm: refused by the travel
    ratio, never printed as a lost motion of millions of um."""
    lines = REPEAT.read_text().splitlines()
    out = []
    for line in lines:
        parts = line.split()
        if parts and parts[0] == RESOLVER:
            line = line.replace(parts[3], f"{float(parts[3]) * COUNTS_PER_MM:.1f}")
        out.append(line)
    path = tmp_path / "counts.log"
    path.write_text("\n".join(out) + "\n")
    line = refused(capsys, ["monitor", str(path), "--log-format", "camonitor", "--axis", "X",
                            "--channels", REAL_CHANNELS])
    assert "IOC_TEST X on 2020-12-09" in line and f"load side {RESOLVER} travels" in line
    assert "raw counts" in line


@needs_logs
def test_real_log_offset_is_said_and_the_scale_states_it():
    """The resolver reads 42.148 mm below the step counter on this log (the unit report's
    83.1304 mm belongs to another power-up): said in a note, and gone with the scale."""
    with pytest.warns(Warning) as caught:
        monitor(REPEAT, format="camonitor", channels=REAL_CHANNELS, axis="X")
    said = [str(w.message) for w in caught if "sits" in str(w.message)]
    assert len(said) == 1 and f"load side {RESOLVER} sits -42.14" in said[0]
    with pytest.warns(Warning) as caught:
        result = monitor(REPEAT, format="camonitor", channels=REAL_CHANNELS, axis="X",
                         reference_scale=(1.0, 42.1484))
    assert not [w for w in caught if "sits" in str(w.message)]
    (row,) = result.daily.itertuples()
    assert row.reversals == 8 and np.isnan(row.lost_motion_um)  # docs/monitor.md: confounded


# --------------------------------------------------------------- samples given twice
def test_a_sample_written_twice_is_dropped_with_a_note(day, tmp_path):
    frame = trace(day)
    twice = pd.concat([frame, frame.iloc[[100, 200, 200]]]).sort_index(kind="stable")
    with pytest.warns(Warning, match=r"trace\.csv: 3 repeated sample\(s\) .* dropped"):
        result = monitor(csv(tmp_path, twice))
    plain = quiet(traces=csv(tmp_path, frame, "plain.csv")).daily
    pd.testing.assert_frame_equal(result.daily, plain)


def test_a_time_given_twice_with_other_values_is_refused(day, tmp_path, capsys):
    frame = trace(day)
    other = frame.iloc[[150]].assign(load_mm=frame.load_mm.iloc[150] + 0.01)
    path = csv(tmp_path, pd.concat([frame, other]).sort_index(kind="stable"))
    line = refused(capsys, ["monitor", path])
    # rows 152 and 153 of the file (header row 1): the original and the other
    assert f"{path}, row 153, column 'load_mm'" in line
    assert "M1 X at 2026-03-02T09:00:01.500000+00:00 is given twice with different values" in line


# ------------------------------------------------------------------------- Dask
def test_a_silent_dask_scheduler_is_refused_within_the_timeout(day, tmp_path, capsys):
    """A port that accepts the connection and never answers: refused after 10 s, not hung."""
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(0.2)
    held, stop = [], time.monotonic() + 20  # the server stops by itself

    def accept():
        while time.monotonic() < stop:
            try:
                held.append(server.accept()[0])
            except OSError:
                continue
        for conn in held:
            conn.close()
        server.close()

    threading.Thread(target=accept, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    done = {}

    def run():
        try:
            done["code"] = main(["monitor", csv(tmp_path, trace(day)), "--engine", "dask",
                                 "--address", address])
        except SystemExit as exit_:
            done["code"] = exit_.code

    began = time.monotonic()
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(15)
    assert not worker.is_alive(), "monitor hung on a silent scheduler"
    assert done["code"] == 2 and time.monotonic() - began < 14
    err = capsys.readouterr().err.strip().splitlines()
    expected = (f"backlash monitor: error: --address: Dask scheduler at {address} did not "
                "answer within 10 s")
    assert err == [expected]


# ---------------------------------------------------------------------- --channels
@pytest.mark.parametrize("channels", [
    f"commanded={SET};motor={MOTOR};load={SCALE}", f"commanded,motor={MOTOR},load={SCALE}",
])
def test_channel_syntax_errors_name_monitors_channels(counts_log, capsys, channels):
    expected = "expected name=PV pairs separated by commas: commanded=PV,motor=PV,load=PV"
    line = refused(capsys, ["monitor", str(counts_log), "--log-format", "camonitor",
                            "--channels", channels])
    assert f"--channels: '{channels.split(',')[0]}' is not name=PV; {expected}" in line
    assert "target" not in line and "reference" not in line and "missing" not in line
