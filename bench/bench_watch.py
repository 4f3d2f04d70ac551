"""``watch``: samples per second per core sustained from each source on loopback, the memory
of a day at 1 kHz on three axes, and the latency from a day's end to its record.

- throughput: a server of ``tests.live_servers`` (or a camonitor file for ``log``) plays two
  axes' trace as fast as the watcher takes it; samples per CPU second of the watcher process
  (its own user + system time, so the server's share and the machine's load are not counted);
- memory: a day at 1 kHz on three axes fed to the stream estimator (``Binner`` then
  ``AxisStream``, as the watcher does) in one-second chunks, in a child process: its peak
  resident set size. Goal < 200 MB. The stream is the day's last ``STREAMED_S`` seconds (six
  hours), then the next day's first second, which closes the day: the peak is that close (the
  day's fit), and what a day keeps is bounded (``models.condition.lost_motion_stream``), so the last
  ten minutes, hour, six hours or the whole day all peak at 58 MB; the whole day took three
  to five minutes of the run;
- latency: a watcher on a log; the first sample of the next day is appended and the time to
  the day's ``day_recorded`` event measured.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import size, verdict

ROOT = Path(__file__).resolve().parents[1]
SECONDS = size(60.0, 6.0)  # trace seconds per day at 50 Hz, two axes
STREAMED_S = size(21_600, 300)  # the memory run streams the day's last seconds [s]
RATE_HZ = 1000
GOAL_MB = 200.0


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a live process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _throughput(protocol: str, folder: Path) -> tuple[int, float, float]:
    """(samples, watcher CPU s, wall s) for one source."""
    import numpy as np

    from tests import test_watch_live as live

    samples = _samples()
    store = folder / protocol / "fleet"
    store.parent.mkdir()
    _new_store(store)
    ns = samples[0]
    n = len(ns)
    with live._processes() as started:
        port = live._free_port()
        if protocol == "log":
            log = folder / protocol / "m1.log"
            log.write_text("")
            config = live._config(folder / protocol / "WATCH.toml", "log", str(log))
        else:
            trace = live._npz(folder / protocol / "trace.npz", protocol, samples)
            address = (f"opc.tcp://127.0.0.1:{port}" if protocol == "opcua"
                       else f"127.0.0.1:{port}")
            config = live._config(folder / protocol / "WATCH.toml", protocol, address)
            server = live._server(started, protocol, trace, port)
        watcher = live._watcher(started, config, store, port)
        watcher.wait_for(live._event("started"))
        pid = watcher.process.pid
        cpu0, wall0 = _cpu_s(pid), time.perf_counter()
        if protocol == "log":
            every = np.arange(n)
            lines = {a: live._camonitor(samples, every, a) for a in live.AXES}
            with open(log, "a") as out:
                out.writelines(line for i in range(n) for a in live.AXES
                               for line in lines[a][3 * i:3 * i + 3])
            live._wait(lambda: live._received_through(store, ns[n - 2]), "every sample")
            cpu, wall = _cpu_s(pid) - cpu0, time.perf_counter() - wall0
        else:
            live._go(server)
            server.wait_for(lambda line: line.startswith("played"), timeout=max(90.0, 0.1 * n))
            # a channel at rest sends nothing, so the last samples wait for the day's end: the
            # watcher is through when its last samples stop moving
            done = _settled_at(store)
            cpu, wall = _cpu_s(pid) - cpu0, done - wall0
    return n * len(live.AXES), cpu, wall


def _settled_at(store, quiet_s: float = 3.0) -> float:
    """The clock when the watcher's last samples last moved (nothing more for ``quiet_s``)."""
    from pipeline.store.live import live_axes

    last, since = None, time.perf_counter()
    while time.perf_counter() - since < quiet_s:
        now = tuple(a["last_sample"] for a in live_axes(store))
        if now != last:
            last, since = now, time.perf_counter()
        time.sleep(0.05)
    return since


_CACHE: dict = {}


def _samples():
    if "samples" not in _CACHE:
        import pandas as pd

        from tests.independent_traces import fleet_traces
        from tests.test_watch_live import AXES

        trace, _ = fleet_traces(seed=11, days=1, seconds=SECONDS, rate_hz=50.0)
        trace = trace.assign(time=trace["time"].dt.floor("us"))
        parts = {a: trace[trace["axis"] == a].sort_values("time").reset_index(drop=True)
                 for a in AXES}
        ns = pd.to_datetime(parts[AXES[0]]["time"], utc=True).array.asi8
        _CACHE["samples"] = (ns, parts, {})
    return _CACHE["samples"]


_MEMORY = """
import sys
import numpy as np
from models.condition.lost_motion_stream import Binner, AxisStream
streamed_s, rate = int(sys.argv[1]), int(sys.argv[2])
t0 = (1_780_000_000 // 86400 * 86400 + 86400 - streamed_s) * 10**9  # streamed_s before a midnight
axes = [(Binner(), AxisStream()) for _ in range(3)]
rng = np.random.default_rng(0)
for s in range(streamed_s + 1):  # one second a chunk, the next day's first second closes it
    ns = t0 + (s * rate + np.arange(rate)) * (10**9 // rate)
    t = ns * 1e-9
    for k, (binner, stream) in enumerate(axes):
        phase = 2 * np.pi * t / (7.0 + k)  # moves at constant feed between reversals
        cmd = 150 + 100 * (2 / np.pi) * np.arcsin(np.sin(phase))
        motor = cmd + rng.normal(0, 5e-5, rate)
        load = motor - 0.002 * np.sign(np.cos(phase))
        stream.feed(*binner.add(ns, cmd, motor, load))
# VmHWM, not ru_maxrss: Linux carries the forking parent's peak across exec into ru_maxrss
status = open("/proc/self/status").read()
print(int(status.split("VmHWM:")[1].split()[0]) / 1024)
"""


def _memory_mb() -> tuple[float, float]:
    started = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", _MEMORY, str(STREAMED_S), str(RATE_HZ)],
                         cwd=ROOT, capture_output=True, text=True, check=True)
    return float(run.stdout.strip().splitlines()[-1]), time.perf_counter() - started


def _latency_s(folder: Path) -> float:
    """Seconds from the next day's first sample appended to the log to the day's record."""
    import numpy as np

    from tests import test_watch_live as live

    samples = _samples()
    ns = samples[0]
    store = folder / "latency" / "fleet"
    store.parent.mkdir()
    _new_store(store)
    log = folder / "latency" / "m1.log"
    every = np.arange(len(ns))
    lines = {a: live._camonitor(samples, every, a) for a in live.AXES}
    log.write_text("".join(line for i in range(len(ns)) for a in live.AXES
                           for line in lines[a][3 * i:3 * i + 3]))
    config = live._config(folder / "latency" / "WATCH.toml", "log", str(log))
    with live._processes() as started:
        watcher = live._watcher(started, config, store, 0)
        live._wait(lambda: live._received_through(store, ns[-2]), "the day")
        names = {a: live._names("log", a) for a in live.AXES}
        begun = time.perf_counter()
        with open(log, "a") as out:
            # the next day's samples in two bins: the first bin complete closes the day,
            # and a third sample releases the second (every channel past it)
            for stamp in ("00:00:00.000000", "00:00:00.050000", "00:00:00.100000"):
                out.writelines(f"{names[a][c]} 2099-01-01 {stamp} 1.0\n" for a in live.AXES
                               for c in ("commanded", "motor", "load"))
        watcher.wait_for(lambda line: line.startswith("{") and json.loads(line)["event"] in (
            "day_recorded", "day_without_value"))
        return time.perf_counter() - begun


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for protocol in ("log", "ca", "pva", "opcua"):
            n, cpu, wall = _throughput(protocol, folder)
            print(f"{protocol}: {n:,} samples ({3 * n:,} channel updates) in {wall:.1f} s, "
                  f"watcher {cpu:.1f} CPU s: {n / max(cpu, 1e-9):,.0f} samples/s per core",
                  flush=True)
        latency = _latency_s(folder)
    print(f"latency from a day's end to its record (log): {latency:.2f} s", flush=True)
    peak, took = _memory_mb()
    print(f"memory: a day's last {STREAMED_S:,} s at {RATE_HZ} Hz on 3 axes through the stream "
          f"estimator, then the day's close: peak RSS {peak:.0f} MB in {took:.0f} s, "
          f"{3 * STREAMED_S * RATE_HZ / took:,.0f} samples/s "
          f"(goal < {GOAL_MB:g} MB): "
          f"{verdict(peak < GOAL_MB)}")


def _new_store(store) -> None:
    """A store of the twin's readings to record into (its "new store" note is expected)."""
    import warnings

    import backlash as bl

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="new store at")
        bl.ingest(ROOT / "experiments/data/twin/readings.csv", store=store)


if __name__ == "__main__":
    main()
