"""``monitor``: lost motion per machine axis and day from dual-feedback traces, checked against
the truth of an independent generator (tests/independent_traces.py) and of the twin; the trace
contract's refusals; the same result in-process and on the Dask engine."""

from __future__ import annotations

import json
import time
import warnings

import numpy as np
import pandas as pd
import pytest

from features.readings.errors import InputError
from features.traces.io import read_trace, write_dataset, write_trace
from models.condition.lost_motion import fit_day, motion_state
from pipeline.cli import main
from pipeline.workflows.monitor import monitor
from tests.independent_traces import axis_day, fleet_traces

START = pd.Timestamp("2026-03-01", tz="UTC")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """The done-when case: 3 axes x 30 days, 60 s at 200 Hz a day, Z adjusted on day 17."""
    trace, truth = fleet_traces(seed=7, days=30)
    path = tmp_path_factory.mktemp("fleet") / "fleet.parquet"
    trace.to_parquet(path, index=False)
    return path, truth


def _rms_by_axis(result, truth) -> pd.Series:
    both = result.daily.merge(truth, on=["machine_id", "axis", "date"], suffixes=("", "_true"))
    assert len(both) == len(truth)
    err = both["lost_motion_um"] - both["lost_motion_um_true"]
    return err.pow(2).groupby(both["axis"]).mean().pow(0.5)


def test_lost_motion_of_an_independent_generator_within_015_um(fleet):
    path, truth = fleet
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = monitor(path)
    rms = _rms_by_axis(result, truth)
    assert (rms < 0.15).all(), rms
    cps = {a.axis: a.change_points for a in result.axes}
    assert cps["X"] == [] and cps["Y"] == []
    # the adjustment took effect on day 17 = 2026-03-18: dated within a day
    (found,) = cps["Z"]
    assert abs((pd.Timestamp(found) - pd.Timestamp("2026-03-18")).days) <= 1
    z = next(a for a in result.axes if a.axis == "Z")
    assert z.slope_um_per_day == pytest.approx(0.08, abs=0.02)  # wear since the adjustment
    # the uncertainty is honest: errors within a few u (not a thousand)
    both = result.daily.merge(truth, on=["machine_id", "axis", "date"], suffixes=("", "_t"))
    z_scores = (both["lost_motion_um"] - both["lost_motion_um_t"]) / both["lost_motion_u_um"]
    assert np.nanmedian(np.abs(z_scores)) < 3  # a day of 3 reversals has no u (too few moves)


def test_monitor_costs_a_few_times_reading_the_parquet_file(fleet):
    """Processor time of ``monitor`` (one core) against ``pd.read_parquet`` of the same file
    (which uses every core): the goal is 3x, measured 2.0-2.2x on a shared development
    machine; this guards at 4x so that a loaded machine does not fail it (docs/monitor.md,
    Speed)."""
    path, _ = fleet
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        monitor(path)  # first imports out of the timing

        def best(run):
            times = []
            for _ in range(3):
                start = time.process_time()
                run()
                times.append(time.process_time() - start)
            return min(times)

        floor = best(lambda: pd.read_parquet(path))
        spent = best(lambda: monitor(path))
    assert spent < 4 * floor, (spent, floor)


def test_twin_traces_recover_the_twins_truth(tmp_path):
    from models.physics.traces import TraceCampaign, simulate_traces

    campaign = TraceCampaign(days=12, seconds=40.0, rate_hz=250.0,
                             axes={"X": {"b0_um": 5.0, "wear_um_per_day": 0.1,
                                         "adjusted_day": 6, "adjusted_b0_um": 2.0}})
    trace, truth = simulate_traces(campaign, seed=4)
    write_dataset(trace, tmp_path / "traces")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = monitor(tmp_path / "traces")
    assert (_rms_by_axis(result, truth) < 0.15).all()
    adjusted = truth.loc[truth["event"] == "adjustment", "date"].item()
    assert result.axes[0].change_points == [adjusted]


def test_a_reversal_shorter_than_the_clearance_is_not_taken_up():
    rate = 100.0
    # out 20 mm, back 0.004 mm (less than any take-up), out again, then a full reversal
    legs = [np.linspace(0, 20, 400), np.full(50, 20.0), np.linspace(20, 19.996, 5),
            np.full(50, 19.996), np.linspace(19.996, 30, 400), np.linspace(30, 10, 400)]
    cmd = np.concatenate(legs)
    t = np.arange(len(cmd)) / rate
    direction, _, usable, _, _ = motion_state(t, cmd)
    short = slice(451, 505)  # from the first step back
    assert not usable[short].any()  # the short move and the rest after it never count
    assert (direction[usable][:10] == 1).all() and (direction[usable][-10:] == -1).all()


def test_fit_separates_lead_error_and_lag_from_the_play():
    rng = np.random.default_rng(3)
    t, cmd, motor, load = axis_day(rng, clearance_um=7.0, seconds=60.0, rate_hz=200.0,
                                   latency_s=0.004)
    fit = fit_day(t, cmd, motor, load)
    assert fit.lost_motion * 1000 == pytest.approx(7.0, abs=0.05)
    assert fit.lag_s == pytest.approx(0.004, rel=0.05)
    assert fit.reversals >= 5


def test_one_feed_without_rests_shows_no_lost_motion():
    """Moves at one feed and no rests: the velocity follows the direction, so lost motion and
    servo lag are confounded; the day is left without a value rather than guessed."""
    from models.physics.axis import play

    t = np.arange(0.0, 60.0, 0.005)
    triangle = 10 + 20 * np.abs((t / 4) % 2 - 1)
    load = np.interp(t - 0.002, t, play(triangle[None, :], np.full((1, len(t)), 4.0))[0])
    fit = fit_day(t, triangle, triangle, load)
    assert fit.reversals > 10 and np.isnan(fit.lost_motion)
    dwell = np.repeat(triangle[::40], 40)[:len(t)]  # the same path with rests: separable
    load = np.interp(t - 0.002, t, play(dwell[None, :], np.full((1, len(t)), 4.0))[0])
    assert fit_day(t, dwell, dwell, load).lost_motion * 1000 == pytest.approx(4.0, abs=0.05)


def test_engine_local_mode_gives_the_in_process_result(tmp_path):
    pytest.importorskip("dask")
    trace, _ = fleet_traces(seed=2, days=3, seconds=20.0)
    write_dataset(trace, tmp_path / "ds")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        here = monitor(tmp_path / "ds")
        there = monitor(tmp_path / "ds", engine="dask")
    pd.testing.assert_frame_equal(here.daily, there.daily, check_exact=True)
    assert here.to_dict() == there.to_dict()


def test_engine_on_a_dask_scheduler_address(tmp_path):
    distributed = pytest.importorskip("distributed")
    trace, _ = fleet_traces(seed=2, days=2, seconds=20.0)
    write_dataset(trace, tmp_path / "ds")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        here = monitor(tmp_path / "ds")
        with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                      dashboard_address=None) as cluster:
            there = monitor(tmp_path / "ds", engine="dask", address=cluster.scheduler_address)
    pd.testing.assert_frame_equal(here.daily, there.daily, check_exact=True)


# --------------------------------------------------------------------------- the CLI
@pytest.fixture(scope="module")
def small(tmp_path_factory):
    trace, _truth = fleet_traces(seed=5, days=8, seconds=30.0)
    folder = tmp_path_factory.mktemp("small")
    write_trace(trace, folder / "trace.csv")
    return folder / "trace.csv", trace


def test_cli_json_report_and_alert_exit(small, tmp_path, capsys):
    path, _ = small
    code = main(["monitor", str(path), "--out", str(tmp_path / "m"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 3  # X and Z grow: an increasing trend is an alert
    axis = out["axes"][0]
    assert set(axis) >= {"machine_id", "axis", "unit", "days", "change_points",
                         "slope_um_per_day"}
    assert set(axis["days"][0]) == {"date", "lost_motion_um", "lost_motion_u_um", "reversals"}
    assert [a["axis"] for a in out["axes"]] == ["X", "Y", "Z"]
    for name in ("monitor.json", "daily.csv", "monitor.html", "monitor.png"):
        assert (tmp_path / "m" / name).is_file()
    assert "lost motion" in (tmp_path / "m" / "monitor.html").read_text()


def _bad(tmp_path, capsys, frame, name="bad.csv"):
    path = tmp_path / name
    if name.endswith(".parquet"):
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    code = main(["monitor", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()
    return err


@pytest.fixture
def rows(small):
    return small[1].iloc[:400].reset_index(drop=True).copy()


def test_time_going_back_is_refused(tmp_path, capsys, rows):
    rows.loc[100, "time"] = rows.loc[10, "time"]
    err = _bad(tmp_path, capsys, rows)
    assert "row 102" in err and "time goes back" in err


def test_a_missing_channel_is_refused(tmp_path, capsys, rows):
    err = _bad(tmp_path, capsys, rows.drop(columns="motor_mm"))
    assert "missing column 'motor_mm'" in err
    rows.loc[5, "commanded_mm"] = np.nan
    err = _bad(tmp_path, capsys, rows)
    assert "row 7" in err and "commanded_mm" in err and "missing value" in err


def test_an_unknown_unit_is_refused(tmp_path, capsys, rows):
    err = _bad(tmp_path, capsys, rows.rename(columns={"load_mm": "load_um"}))
    assert "'load_um'" in err and "unknown unit 'um'" in err
    err = _bad(tmp_path, capsys, rows.rename(columns={"motor_mm": "motor_deg"}))
    assert "deg on linear axis" in err
    numbers = rows.assign(time=np.arange(len(rows)) * 0.005)
    assert "unknown unit and epoch" in _bad(tmp_path, capsys, numbers)


def test_an_unknown_axis_is_refused(tmp_path, capsys, rows):
    rows.loc[3, "axis"] = "Q"
    assert "unknown axis 'Q'" in _bad(tmp_path, capsys, rows, "bad.parquet")


def test_a_trace_without_load_side_position_is_refused(tmp_path, capsys, rows):
    err = _bad(tmp_path, capsys, rows.drop(columns="load_mm"))
    assert "lost motion needs a load-side position" in err


def test_a_rotary_axis_reports_arcsec(tmp_path, rows):
    rotary = rows.assign(axis="C").rename(columns={c: c.replace("_mm", "_deg") for c in
                                                   ("commanded_mm", "motor_mm", "load_mm")})
    write_trace(rotary, tmp_path / "c.csv")
    read = read_trace(tmp_path / "c.csv")
    assert list(read.columns[:5]) == ["time", "machine_id", "axis", "commanded_mm", "motor_mm"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert monitor(read).axes[0].unit == "arcsec"


def test_a_day_given_twice_is_refused(small):
    path, _ = small
    with pytest.raises(InputError, match="in two inputs"):
        monitor([path, path])


def test_simulate_writes_twin_traces_and_refuses_a_rate_out_of_range(tmp_path, capsys):
    assert main(["simulate", "--traces", "--days", "2", "--seed", "1",
                 "--out", str(tmp_path / "tw")]) == 0
    truth = pd.read_csv(tmp_path / "tw" / "traces_truth.csv")
    assert sorted(truth["axis"].unique()) == ["X", "Y", "Z"] and len(truth) == 6
    assert (tmp_path / "tw" / "traces" / "machine_id=M01" / "axis=X" / "date=2026-03-02"
            / "part-0.parquet").is_file()
    capsys.readouterr()
    assert main(["simulate", "--traces", "--rate-hz", "50", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--rate-hz" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "b").exists()


def test_time_may_interleave_axes_but_never_go_back_within_one():
    from features.traces.validation import check_trace

    t = pd.date_range("2026-03-01", periods=6, freq="10ms", tz="UTC")
    frame = pd.DataFrame({"time": t[[0, 0, 1, 1, 2, 2]], "machine_id": "M", "axis":
                          ["X", "Y"] * 3, "commanded_mm": 1.0, "motor_mm": 1.0})
    assert len(check_trace(frame, "f.csv")) == 6  # X and Y rows alternate: fine
    frame.loc[5, "time"] = t[0]  # Y goes back from t[1] to t[0] at row 5 + 2
    with pytest.raises(InputError, match="row 7.*time goes back"):
        check_trace(frame, "f.csv")


def test_a_dataset_is_read_one_partition_at_a_time(tmp_path):
    from features.traces.io import partitions, read_partition

    trace, _ = fleet_traces(seed=3, days=2, seconds=10.0)
    write_dataset(trace, tmp_path / "ds")
    parts = partitions(tmp_path / "ds")
    assert [(p.machine_id, p.axis, p.date) for p in parts][:2] == [
        ("M7", "X", "2026-03-01"), ("M7", "X", "2026-03-02")]
    assert len(parts) == 6
    one = read_partition(parts[0])
    assert len(one) == len(trace) // 6 and set(one["axis"]) == {"X"}
    # a file holding another machine than its folder names is refused
    stray = tmp_path / "ds" / "machine_id=M8" / "axis=X" / "date=2026-03-01"
    stray.mkdir(parents=True)
    (tmp_path / "ds" / "machine_id=M7" / "axis=X" / "date=2026-03-01" / "part-0.parquet"
     ).rename(stray / "part-0.parquet")
    with pytest.raises(InputError, match="holds machine_id other than 'M8'"):
        monitor(tmp_path / "ds")
    (tmp_path / "ds" / "notes").mkdir()
    (tmp_path / "ds" / "notes" / "x.parquet").write_bytes(b"")
    with pytest.raises(InputError, match="is no partition"):
        partitions(tmp_path / "ds")


def test_an_address_needs_the_dask_engine(small):
    with pytest.raises(InputError, match="takes no address") as err:
        monitor(small[0], address="tcp://127.0.0.1:8786")
    assert err.value.parameter == "address"
