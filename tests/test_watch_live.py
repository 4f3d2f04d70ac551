"""``watch`` against real servers on 127.0.0.1 (``tests.live_servers``): an EPICS Channel Access
IOC (caproto), a PV Access server (p4p) and an OPC UA server with OPC 40502-style axis nodes
(asyncua), each playing a trace of known truth with the trace's own timestamps, as fast as the
watcher takes it. The days recorded equal ``monitor`` on the samples that arrived, written as a
camonitor file; a server killed mid-day and restarted seconds later is a gap the day reports
(samples expected against received), never a doubled day; a PV or node that does not exist,
a channel in another unit and a clock that runs backwards are refused in one line, exit 2.

Every wait is on a condition with a bounded timeout; servers and watchers are killed by their
own process ids at the end of each test whatever happened.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import backlash as bl
from pipeline.store.live import live_axes
from pipeline.store.records import read_records
from pipeline.workflows.monitor import monitor
from tests.independent_traces import fleet_traces

ROOT = Path(__file__).resolve().parents[1]
AXES = ("X", "Y")
CHANNELS = (("commanded", "commanded_mm"), ("motor", "motor_mm"), ("load", "load_mm"))
# A 40 s day at 50 Hz finds the clearance within this [um] (its moves, not the watcher)
TRUTH_UM = 0.5
WAIT_S = 90.0  # the longest any condition is waited for on a loaded machine


def _names(protocol: str, axis: str) -> dict:
    """Each channel's name on the server: ecmc-style PVs, or OPC 40502 browse paths."""
    if protocol == "opcua":
        return {"commanded": f"M1/{axis}/CmdPos", "motor": f"M1/{axis}/PosIndirect/ActPos",
                "load": f"M1/{axis}/PosDirect/ActPos"}
    return {"commanded": f"M1:{axis}-PosSet", "motor": f"M1:{axis}-PosAct",
            "load": f"M1:{axis}-PosLoad"}


@pytest.fixture(scope="module")
def samples():
    """Three short days (40 s at 50 Hz) of two axes on one clock: (ns, {axis: frame}, truth
    {(axis, date): lost motion [um]})."""
    trace, truth = fleet_traces(seed=11, days=3, seconds=40.0, rate_hz=50.0)
    trace = trace.assign(time=trace["time"].dt.floor("us"))
    parts = {a: trace[trace["axis"] == a].sort_values("time").reset_index(drop=True)
             for a in AXES}
    ns = pd.to_datetime(parts[AXES[0]]["time"], utc=True).array.asi8
    return ns, parts, {(r.axis, r.date): r.lost_motion_um for r in truth.itertuples()}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    folder = tmp_path_factory.mktemp("live") / "fleet"
    bl.ingest(ROOT / "experiments/data/twin/readings.csv", store=folder)
    return folder


def _store(fleet: Path, tmp: Path) -> Path:
    """A fresh copy of the fleet store (each test its own days)."""
    import shutil

    shutil.copytree(fleet, tmp / "fleet")
    return tmp / "fleet"


def _npz(path: Path, protocol: str, samples, units=None) -> Path:
    ns, parts, _ = samples
    names, columns = [], []
    for axis in AXES:
        for channel, column in CHANNELS:
            names.append(_names(protocol, axis)[channel])
            columns.append(parts[axis][column].to_numpy())
    extra = {} if units is None else {"units": np.array(units)}
    np.savez(path, names=np.array(names), ns=ns, values=np.stack(columns, 1), **extra)
    return path


def _config(path: Path, protocol: str, address: str, extra: str = "", axes=AXES) -> Path:
    text = f'[source]\nprotocol = "{protocol}"\naddress = "{address}"\n{extra}\n'
    for axis in axes:
        names = _names(protocol, axis)
        text += f'[[axis]]\nmachine_id = "M1"\naxis = "{axis}"\n'
        if protocol == "opcua":  # the OPC 40502 axis node, its channels by browse name
            text += f'node = "M1/{axis}"\n'
            continue
        text += "".join(f'{c} = "{names[c]}"\n' for c, _ in CHANNELS)
    path.write_text(text)
    return path


def _free_port() -> int:
    """A port free on 127.0.0.1 for TCP and UDP, and the next one for UDP (CA's beacons)."""
    for _ in range(50):
        with socket.socket() as tcp:
            tcp.bind(("127.0.0.1", 0))
            port = tcp.getsockname()[1]
        try:
            for p in (port, port + 1):
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
                    udp.bind(("127.0.0.1", p))
            return port
        except OSError:
            continue
    raise RuntimeError("no free port pair on 127.0.0.1")


def _env(port: int) -> dict:
    """Client environment: loopback only, non-default ports, never a broadcast."""
    return {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true", "EPICS_CA_AUTO_ADDR_LIST": "NO",
            "EPICS_CA_ADDR_LIST": "127.0.0.1", "EPICS_CA_SERVER_PORT": str(port),
            "EPICS_CA_REPEATER_PORT": str(port + 1), "EPICS_PVA_AUTO_ADDR_LIST": "NO",
            "EPICS_PVA_ADDR_LIST": "127.0.0.1", "EPICS_PVA_BROADCAST_PORT": str(port + 1),
            "EPICS_PVA_SERVER_PORT": str(port), "PYTHONUNBUFFERED": "1"}


class Lines:
    """A process's stdout lines as they come, read by a thread, waited on with a bound."""

    def __init__(self, process: subprocess.Popen):
        self.process, self.lines, self.fresh = process, [], queue.Queue()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line)
            self.fresh.put(line)

    def wait_for(self, predicate, timeout: float = WAIT_S) -> str:
        seen = [line for line in list(self.lines) if predicate(line)]
        if seen:
            return seen[0]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None and self.fresh.empty():
                break
            try:
                line = self.fresh.get(timeout=0.2)
            except queue.Empty:
                continue
            if predicate(line):
                return line
        raise AssertionError(f"waited {timeout:g} s in vain; last lines: {self.lines[-5:]}; "
                             f"stderr: {_stderr(self.process)}")


def _stderr(process) -> str:
    path = getattr(process, "stderr_path", None)
    return path.read_text()[-2000:] if path is not None and path.exists() else ""


def _popen(started, argv, port: int, stderr: Path) -> subprocess.Popen:
    """A child whose stderr goes to a file (a pipe nobody reads would block it once full)."""
    with open(stderr, "w") as err:
        p = subprocess.Popen(argv, cwd=ROOT, env=_env(port), stdout=subprocess.PIPE,
                             stderr=err, stdin=subprocess.PIPE, text=True)
    p.stderr_path = stderr
    started.append(p)
    return p


@contextlib.contextmanager
def _processes():
    """Processes started in a test, each killed by its own id at the end."""
    started: list[subprocess.Popen] = []
    try:
        yield started
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
            with contextlib.suppress(Exception):
                p.wait(timeout=10)


def _server(started, protocol: str, trace: Path, port: int, start: int = 0,
            stop: int | None = None) -> Lines:
    argv = [sys.executable, "-m", "tests.live_servers", protocol, str(trace), "--port",
            str(port), "--start", str(start), "--linger", "240"]
    if stop is not None:
        argv += ["--stop", str(stop)]
    p = _popen(started, argv, port, trace.with_name(f"server-{len(started)}.err"))
    lines = Lines(p)
    lines.wait_for(lambda line: line.startswith("ready"))
    return lines


def _watcher(started, config: Path, store: Path, port: int) -> Lines:
    p = _popen(started, [sys.executable, "-m", "pipeline.cli", "watch", str(config), "--store",
                         str(store), "--json", "--no-track"], port,
               config.with_name(f"watch-{len(started)}.err"))
    return Lines(p)


def _go(server: Lines) -> None:
    server.process.stdin.write("go\n")
    server.process.stdin.flush()


def _event(name: str):
    return lambda line: line.startswith("{") and json.loads(line).get("event") == name


def _played(n: int):
    return lambda line: line.strip() == f"played {n}"


def _wait(predicate, what: str, timeout: float = WAIT_S):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"waited {timeout:g} s in vain for {what}")


def _received_through(store: Path, ns: int) -> bool:
    """Every axis's last sample (released only once all its channels passed it) at ``ns``."""
    stamp = str(np.datetime64(int(ns), "ns"))[:26] + "Z"
    last = {a["axis"]: a["last_sample"] for a in live_axes(store)}
    return all(last.get(axis) is not None and last[axis] >= stamp for axis in AXES)


def _days_recorded(store: Path, count: int) -> bool:
    records = read_records(store, "trace")
    return all(len(records.get(("M1", a), [])) >= count for a in AXES)


def _camonitor(samples, keep: np.ndarray, axis: str) -> list[str]:
    """camonitor lines of the samples ``keep`` of one axis (its three PVs per sample)."""
    frame = samples[1][axis].iloc[keep]
    stamp = frame["time"].dt.strftime("%Y-%m-%d %H:%M:%S.%f").to_numpy()
    names = _names("ca", axis)
    return [f"{names[c]} {s} {v:.17g}\n" for i, s in enumerate(stamp)
            for c, column in CHANNELS for v in [frame[column].iat[i]]]


def _monitor_days(tmp: Path, samples, keep: np.ndarray, axis: str) -> pd.DataFrame:
    """``monitor`` on the samples ``keep`` of one axis, as a camonitor file of its PVs."""
    names = _names("ca", axis)
    path = tmp / f"arrived-{axis}.log"
    path.write_text("".join(_camonitor(samples, keep, axis)))
    daily = monitor(path, format="camonitor", channels=names, machine="M1").daily
    return daily.dropna(subset=["lost_motion_um"]).reset_index(drop=True)


def _assert_monitor(store: Path, tmp: Path, samples, keep: np.ndarray) -> dict:
    """The recorded days are monitor's on the samples kept, each once; returns them."""
    records = read_records(store, "trace")
    out = {}
    for axis in AXES:
        days = records[("M1", axis)]
        batch = _monitor_days(tmp, samples, keep, axis)
        assert [d["date"] for d in days] == list(batch["date"])  # each day once
        for day, row in zip(days, batch.itertuples(), strict=True):
            assert abs(day["lost_motion_um"] - samples[2][axis, day["date"]]) < TRUTH_UM
            assert day["reversals"] == row.reversals
            assert abs(day["lost_motion_um"] - row.lost_motion_um) < 1e-9
            assert abs(day["lost_motion_u_um"] - row.lost_motion_u_um) < 1e-9
        out[axis] = days
    return out


def _day_bounds(ns: np.ndarray) -> list[tuple[int, int]]:
    day = ns // 86_400_000_000_000
    cuts = np.flatnonzero(np.diff(day)) + 1
    return list(zip(np.r_[0, cuts], np.r_[cuts, len(ns)]))


def _killed_mid_day(protocol: str, samples, fleet: Path, tmp: Path, extra: str = ""):
    """A server plays day 1 and half of day 2, is killed (SIGKILL), stays away a few seconds
    while the watcher keeps running, comes back at a later sample and plays on into day 3;
    returns (store, the samples that were sent, the gap's first and end sample, events)."""
    ns = samples[0]
    _, d2, d3 = _day_bounds(ns)
    a = d2[0] + (d2[1] - d2[0]) // 2  # the server dies after sample a - 1
    b = a + 150  # and comes back at sample b: 3 s of the day never sent
    n = d3[0] + 5  # a few samples of day 3 close day 2
    port = _free_port()
    trace = _npz(tmp / "trace.npz", protocol, samples)
    store = _store(fleet, tmp)
    address = {"ca": f"127.0.0.1:{port}", "pva": f"127.0.0.1:{port}",
               "opcua": f"opc.tcp://127.0.0.1:{port}"}[protocol]
    config = _config(tmp / "WATCH.toml", protocol, address, extra)
    with _processes() as started:
        first = _server(started, protocol, trace, port, 0, a)
        watcher = _watcher(started, config, store, port)
        watcher.wait_for(_event("started"))
        _go(first)
        first.wait_for(_played(a))
        # all of the first server's samples are in before it dies: the last one is released
        # once every channel passed it, so the one before it shows as the last sample
        _wait(lambda: _received_through(store, ns[a - 2]), "the first server's samples")
        started[0].send_signal(signal.SIGKILL)
        started[0].wait(timeout=10)
        watcher.wait_for(_event("source_down"))
        second = _server(started, protocol, trace, port, b, n)
        watcher.wait_for(_event("source_up"))
        _go(second)
        second.wait_for(_played(n))
        _wait(lambda: _days_recorded(store, 2), "days 1 and 2 recorded")
        watcher.process.send_signal(signal.SIGTERM)  # keeps day 3 open
        watcher.wait_for(_event("stopped"))
        assert watcher.process.wait(timeout=30) == 0
    lines = [json.loads(line) for line in watcher.lines if line.startswith("{")]
    events = [e for e in lines if "event" in e]  # the last line is the result
    keep = np.r_[0:a, b:n]
    return store, keep, (a, b), events


@pytest.mark.parametrize("protocol", ["ca", "pva", "opcua"])
def test_monitors_days_and_the_gap_of_a_server_killed_mid_day(protocol, samples, fleet,
                                                              tmp_path):
    store, keep, (a, b), events = _killed_mid_day(protocol, samples, fleet, tmp_path)
    days = _assert_monitor(store, tmp_path, samples, keep)
    ns = samples[0]
    (d1, d2, _) = _day_bounds(ns)
    for axis in AXES:
        first, second = days[axis]
        assert first["samples_received"] == first["samples_expected"] == d1[1] - d1[0]
        assert first["coverage"] == 1.0
        # the gap: the samples the IOC never sent are expected and not received
        assert second["samples_received"] == d2[1] - d2[0] - (b - a)
        assert second["samples_expected"] == d2[1] - d2[0]
        assert second["coverage"] == pytest.approx((d2[1] - d2[0] - (b - a)) / (d2[1] - d2[0]),
                                                   abs=1e-6)
    kinds = [e["event"] for e in events]
    assert kinds.index("source_down") < kinds.index("source_up")


def _refused(started, config: Path, store: Path, port: int, limit_s: float):
    """Run watch to its refusal: (its one line, seconds it took); the event lines before it
    (started) are the watcher's log, not part of the refusal."""
    begun = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "pipeline.cli", "watch", str(config), "--store",
                          str(store), "--for", "30", "--no-track"], cwd=ROOT, env=_env(port),
                         capture_output=True, text=True, timeout=WAIT_S, check=False)
    took = time.monotonic() - begun
    lines = [line for line in run.stderr.strip().splitlines() if not line[:4].isdigit()]
    assert run.returncode == 2, run.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("backlash watch: error:"), run.stderr[-2000:]
    assert took < limit_s
    return lines[0], took


@pytest.mark.parametrize("protocol", ["ca", "pva", "opcua"])
def test_a_channel_that_does_not_exist_fails_within_its_timeout(protocol, samples, fleet,
                                                                tmp_path):
    port = _free_port()
    trace = _npz(tmp_path / "trace.npz", protocol, samples)
    address = (f"opc.tcp://127.0.0.1:{port}" if protocol == "opcua" else f"127.0.0.1:{port}")
    config = _config(tmp_path / "WATCH.toml", protocol, address, "timeout_s = 2")
    missing = {"ca": "M1:Y-PosNone", "pva": "M1:Y-PosNone", "opcua": "M1/Y/PosNone"}[protocol]
    text = config.read_text()
    if protocol == "opcua":
        text = text.replace('node = "M1/Y"', 'commanded = "M1/Y/CmdPos"\nmotor = '
                            f'"M1/Y/PosIndirect/ActPos"\nload = "{missing}"')
    else:
        text = text.replace(_names(protocol, "Y")["load"], missing)
    config.write_text(text)
    with _processes() as started:
        _server(started, protocol, trace, port)
        # the start-up allows timeout_s (2 s) for the server to answer; the rest is start-up
        line, _ = _refused(started, config, _store(fleet, tmp_path), port, limit_s=2 + 45)
    assert missing in line and ("does not answer" in line or "does not exist" in line)


@pytest.mark.parametrize("protocol", ["ca", "pva", "opcua"])
def test_a_channel_in_counts_is_refused(protocol, samples, fleet, tmp_path):
    port = _free_port()
    units = ["mm"] * 3 * len(AXES)
    units[2] = "counts"  # X's load-side encoder reports counts
    trace = _npz(tmp_path / "trace.npz", protocol, samples, units)
    address = (f"opc.tcp://127.0.0.1:{port}" if protocol == "opcua" else f"127.0.0.1:{port}")
    config = _config(tmp_path / "WATCH.toml", protocol, address, "timeout_s = 5")
    with _processes() as started:
        _server(started, protocol, trace, port)
        line, _ = _refused(started, config, _store(fleet, tmp_path), port, limit_s=WAIT_S)
    assert _names(protocol, "X")["load"] in line and "'counts'" in line and "expected mm" in line


def _log_config(tmp: Path, lines: list[str]) -> Path:
    log = tmp / "m1.log"
    log.write_text("".join(lines))
    return _config(tmp / "WATCH.toml", "log", str(log), axes=("X",))


def test_values_clearly_in_counts_are_refused(fleet, tmp_path):
    names = _names("log", "X")
    lines = [f"{names[c]} 2026-03-01 09:00:0{i}.000000 {v}\n" for i in range(3)
             for c, v in (("commanded", 10.0 + i), ("motor", 10.0 + i), ("load", 4096000 + i))]
    config = _log_config(tmp_path, lines)
    line, _ = _refused([], config, _store(fleet, tmp_path), 0, limit_s=WAIT_S)
    assert names["load"] in line and "not encoder counts" in line


def test_a_source_whose_clock_runs_backwards_is_refused(fleet, tmp_path):
    names = _names("log", "X")
    times = ["09:00:01", "09:00:02", "09:00:00"]  # the third sample before the second
    lines = [f"{names[c]} 2026-03-01 {t}.000000 {10.0 + i}\n" for i, t in enumerate(times)
             for c in ("commanded", "motor", "load")]
    config = _log_config(tmp_path, lines)
    store = _store(fleet, tmp_path)
    line, _ = _refused([], config, store, 0, limit_s=WAIT_S)
    assert "clock runs backwards" in line and names["commanded"] in line
    assert not read_records(store, "trace")  # nothing recorded


def test_a_rotated_and_a_truncated_log_lose_nothing_and_double_nothing(samples, fleet, tmp_path):
    ns = samples[0]
    every = np.arange(len(ns))
    lines = {axis: _camonitor(samples, every, axis) for axis in AXES}
    both = [line for i in range(len(ns)) for axis in AXES
            for line in lines[axis][3 * i:3 * i + 3]]  # the axes' samples interleaved
    per_sample = 3 * len(AXES)
    (d1, d2, d3) = _day_bounds(ns)
    rotate, truncate = (d1[1] + d2[0]) // 2 + 400, d2[0] + (d2[1] - d2[0]) // 2
    rotate, truncate = rotate * per_sample, truncate * per_sample
    log = tmp_path / "m1.log"
    log.write_text("".join(both[:rotate - 600]))
    config = _config(tmp_path / "WATCH.toml", "log", str(log))
    store = _store(fleet, tmp_path)
    with _processes() as started:
        watcher = _watcher(started, config, store, 0)
        watcher.wait_for(_event("started"))
        _wait(lambda: _received_through(store, ns[(rotate - 600) // per_sample - 2]),
              "the first lines")
        with open(log, "a") as out:  # lines the watcher has not read when the file is renamed
            out.writelines(both[rotate - 600:rotate])
        log.rename(tmp_path / "m1.log.1")
        log.write_text("".join(both[rotate:truncate]))
        watcher.wait_for(_event("log_rotated"))
        _wait(lambda: _received_through(store, ns[truncate // per_sample - 2]), "the new file")
        # rewritten shorter, starting with lines it had already (as a logger that restarts
        # from its own buffer): those are not taken twice
        log.write_text("".join(both[truncate - 300:truncate + 30]))
        watcher.wait_for(_event("log_truncated"))
        with open(log, "a") as out:
            out.writelines(both[truncate + 30:d3[0] * per_sample + 5 * per_sample])
        _wait(lambda: _days_recorded(store, 2), "days 1 and 2 recorded")
        watcher.process.send_signal(signal.SIGTERM)  # keeps day 3 open
        watcher.wait_for(_event("stopped"))
        assert watcher.process.wait(timeout=30) == 0
    days = _assert_monitor(store, tmp_path, samples, np.arange(d3[0] + 5))
    for axis in AXES:  # every sample once: the days as whole as monitor's
        assert [d["samples_received"] for d in days[axis]] == [d1[1] - d1[0], d2[1] - d2[0]]


def _watched(store: Path, last_sample: str, stale_after_s=None) -> None:
    """A watcher's saved state naming M01 X (as ``pipeline.live.loop`` writes it)."""
    from pipeline.store.live import live_folder, save_state
    from pipeline.store.records import open_for_records

    meta = {"axes": [{"machine_id": "M01", "axis": "X", "last_sample": last_sample,
                      "stale_after_s": stale_after_s, "source": "WATCH.toml"}]}
    save_state(live_folder(open_for_records(store)), "watch__WATCH", "state", {}, meta)


@pytest.mark.parametrize("last, limit, stale", [
    ("2026-06-30T20:00:00.000000Z", None, False),  # 4 h before the view's end: live
    ("2026-06-27T23:00:00.000000Z", None, True),   # 3 days: past the default 2 days
    ("2026-06-30T20:00:00.000000Z", 3600.0, True),  # its WATCH.toml allows an hour only
])
def test_fleet_shows_a_watched_axis_last_sample_and_alerts_when_it_goes_silent(
        fleet, tmp_path, last, limit, stale):
    store = _store(fleet, tmp_path)
    _watched(store, last, limit)
    axes = {(a["machine_id"], a["axis"]): a
            for a in bl.fleet(store, as_of="2026-06-30").to_dict()["axes"]}
    x = axes["M01", "X"]
    assert x["last_sample"] == last
    assert x["stale_after_s"] == (limit or 2 * 86400.0)
    assert ("source_stale" in x["alerts"]) is stale
    assert all(a["last_sample"] is None for k, a in axes.items() if k != ("M01", "X"))
