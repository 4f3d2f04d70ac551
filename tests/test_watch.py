"""``watch``: a camonitor log appended to while the watcher runs gives the same days, values and
reversals as ``monitor`` on the finished file, each day recorded once though the watcher is
killed (SIGKILL) and restarted mid-way; the streaming estimator equals the batch one; bad
configurations are refused with one line and exit 2."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings.errors import InputError
from features.traces.validation import check_trace
from models.condition.lost_motion import daily_lost_motion
from models.condition.lost_motion_stream import AxisStream, Binner, stream_days
from pipeline.store.records import read_records
from pipeline.workflows.monitor import monitor
from tests.independent_traces import fleet_traces

ROOT = Path(__file__).resolve().parents[1]
AXES = ("X", "Y", "Z")


def _pvs(axis: str) -> dict:
    return {"commanded": f"M1:{axis}-PosSet", "motor": f"M1:{axis}-PosAct",
            "load": f"M1:{axis}-PosLoad"}


def _config(path: Path, address: str, protocol: str = "log", extra: str = "") -> Path:
    text = f'[source]\nprotocol = "{protocol}"\naddress = "{address}"\n{extra}\n'
    for axis in AXES:
        pv = _pvs(axis)
        text += (f'[[axis]]\nmachine_id = "M1"\naxis = "{axis}"\ncommanded = "{pv["commanded"]}"'
                 f'\nmotor = "{pv["motor"]}"\nload = "{pv["load"]}"\n')
    path.write_text(text)
    return path


def _log_lines(trace: pd.DataFrame) -> list[str]:
    """camonitor lines of a trace (three PVs per sample, the times of a camonitor log: us)."""
    stamp = trace["time"].dt.strftime("%Y-%m-%d %H:%M:%S.%f").to_numpy()
    lines = []
    for channel, column in (("commanded", "commanded_mm"), ("motor", "motor_mm"),
                            ("load", "load_mm")):
        pv = trace["axis"].map(lambda a, c=channel: _pvs(a)[c]).to_numpy()
        lines.append(pd.DataFrame({"order": np.arange(len(trace)), "c": len(lines),
                                   "line": pv + " " + stamp + " "
                                   + trace[column].map("{:.6f}".format).to_numpy()}))
    both = pd.concat(lines).sort_values(["order", "c"], kind="stable")
    return list(both["line"] + "\n")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    folder = tmp_path_factory.mktemp("watch")
    bl.ingest(ROOT / "experiments/data/twin/readings.csv", store=folder / "fleet")
    return folder


def _watch(config: Path, store: Path, seconds: float) -> subprocess.Popen:
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    return subprocess.Popen([sys.executable, "-m", "pipeline.cli", "watch", str(config),
                             "--store", str(store), "--for", str(seconds), "--json",
                             "--no-track"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def test_a_growing_log_gives_monitors_days_once_though_killed(store):
    trace, _ = fleet_traces(seed=5, days=3, seconds=60.0, rate_hz=100.0)
    trace = trace.assign(time=trace["time"].dt.floor("us")).sort_values("time", kind="stable")
    lines = _log_lines(trace)
    log = store / "m1.log"
    log.write_text("")
    config = _config(store / "WATCH.toml", str(log))
    fleet = store / "fleet"
    third = len(lines) // 3
    first = _watch(config, fleet, 120)
    with open(log, "a") as out:  # a day and a half while the first watcher runs
        for i in range(0, third + third // 2, 2000):
            out.writelines(lines[i:min(i + 2000, third + third // 2)])
            out.flush()
            time.sleep(0.01)
    deadline = time.time() + 60
    while time.time() < deadline and not read_records(fleet, "trace"):
        time.sleep(0.2)
    time.sleep(1.5)  # past a state save
    first.send_signal(signal.SIGKILL)
    first.wait()
    recorded_before = sum(len(v) for v in read_records(fleet, "trace").values())
    # the first day of each axis that has an uncertainty (a day of 3 reversals has too few
    # moves for one and is not recorded: docs/monitor.md)
    stated = daily_lost_motion(check_trace(trace, "trace")).dropna(
        subset=["lost_motion_um", "lost_motion_u_um"])
    first_day = stated["date"] == stated["date"].min()
    assert recorded_before == int(first_day.sum()) >= 2
    with open(log, "a") as out:  # the rest, while no watcher runs and after it restarts
        out.writelines(lines[third + third // 2:2 * third])
    second = _watch(config, fleet, 6)
    with open(log, "a") as out:
        out.writelines(lines[2 * third:])
    out_text, err = second.communicate(timeout=90)
    assert second.returncode == 0, err
    records = read_records(fleet, "trace")
    for axis in AXES:
        days = records[("M1", axis)]  # each day once, whatever the restart
        batch = monitor(log, format="camonitor", channels=_pvs(axis), machine="M1").daily
        batch = batch.dropna(subset=["lost_motion_um", "lost_motion_u_um"])
        assert [d["date"] for d in days] == list(batch["date"]), out_text[-2000:]
        assert len(days) >= 2
        for day, row in zip(days, batch.itertuples(), strict=True):
            assert day["reversals"] == row.reversals
            assert abs(day["lost_motion_um"] - row.lost_motion_um) < 1e-9
            assert abs(day["lost_motion_u_um"] - row.lost_motion_u_um) < 1e-9
            assert day["coverage"] == pytest.approx(1.0, abs=0.01)
    assert '"event": "day_recorded"' in out_text


def test_the_stream_equals_the_batch_in_any_pieces_and_across_restarts():
    trace, _ = fleet_traces(seed=3, days=2, seconds=30.0, rate_hz=200.0)
    part = trace[trace["axis"] == "X"]
    ns = pd.to_datetime(part["time"], utc=True).array.asi8
    channels = [part[c].to_numpy() for c in ("commanded_mm", "motor_mm", "load_mm")]
    whole = stream_days(ns, *channels)
    rng = np.random.default_rng(0)
    binner, stream, days, i = Binner(), AxisStream(), [], 0
    while i < len(ns):
        j = i + int(rng.integers(1, 3000))
        days += stream.feed(*binner.add(ns[i:j], *(c[i:j] for c in channels)))
        state = {**stream.to_arrays("s"), **binner.to_arrays("b")}  # a restart
        stream, binner, i = AxisStream.from_arrays(state, "s"), Binner.from_arrays(state, "b"), j
    days += stream.feed(*binner.flush()) + stream.close()
    assert [d for d, _ in days] == [d for d, _ in whole]
    for (_, a), (_, b) in zip(days, whole):
        # a day of few moves has a value without an uncertainty (NaN) in both
        assert a[2] == b[2] and abs(a[0] - b[0]) * 1000 < 1e-9
        assert np.isnan(a[1]) == np.isnan(b[1])
        assert np.isnan(a[1]) or abs(a[1] - b[1]) * 1000 < 1e-9


@pytest.mark.parametrize("change, message", [
    (lambda t: t.replace('motor = "M1:Y-PosAct"', 'motor = "M1:X-PosAct"'), "feeds two axes"),
    (lambda t: t.replace('protocol = "log"', 'protocol = "modbus"'), "protocol 'modbus'"),
    (lambda t: t.replace('load = "M1:Z-PosLoad"\n', ''), "no load channel"),
])
def test_a_bad_configuration_is_one_line_and_exit_2(tmp_path, store, change, message):
    config = _config(tmp_path / "WATCH.toml", str(tmp_path / "x.log"))
    config.write_text(change(config.read_text()))
    run = subprocess.run([sys.executable, "-m", "pipeline.cli", "watch", str(config), "--store",
                          str(store / "fleet"), "--for", "1", "--no-track"], cwd=ROOT, check=False,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and message in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_a_log_that_never_appears_fails_within_its_timeout(tmp_path, store):
    config = _config(tmp_path / "WATCH.toml", str(tmp_path / "none.log"), extra="timeout_s = 0.5")
    started = time.time()
    with pytest.raises(InputError, match="does not exist after 0.5 s"):
        bl.watch(config, store=store / "fleet", seconds=5)
    assert time.time() - started < 5


def test_a_store_that_cannot_be_written_is_refused(tmp_path, store):
    """The watcher's state folder taken by a file: no one, root included, can write there."""
    config = _config(tmp_path / "WATCH.toml", str(tmp_path / "x.log"))
    fleet = store / "fleet"
    live = fleet / "live"
    if live.is_dir():
        shutil.rmtree(live)
    live.write_text("not a folder")
    with pytest.raises(InputError, match="cannot write the watcher's state"):
        bl.watch(config, store=fleet, seconds=1)
