"""Parsing a multi-MB EPICS camonitor log, as a ratio to ``pandas.read_csv`` of the same file
measured in the same run (best of ``REPEATS`` each, interleaved so machine load hits both
alike): ``parse_camonitor`` (every line: PV, UTC time, value, alarm fields, row) and
``read_camonitor`` (three PVs as forward-filled channels, with the time-order checks).

The log is an ISO 230-2 run of 9 targets x 5 cycles written in the real ecmc logs' format by
``tests.camonitor_logs`` at 100 Hz (about 0.28 million lines, 20 MB). The reference reads the
same file with ``sep=r"\\s+"`` into six string columns, no time parsing: the floor of any
reader of it.

Goal: ``parse_camonitor`` <= 3x the reference, ``read_camonitor`` <= 4x.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench import size

REPEATS = size(3, 1)
TARGETS, CYCLES = size(9, 2), size(5, 1)
GOALS = {"parse_camonitor": 3.0, "read_camonitor": 4.0}
PVS = {"REF_PV": "IOC_TEST:m0s012-Enc01-PosAct", "TEST_PV": "IOC_TEST:TestNumber",
       "TGT_SET_PV": "IOC_TEST:Axis1-PosSet"}


def _log(folder: Path) -> Path:
    from tests.camonitor_logs import run_readings, write_run

    targets = {i: 10.0 + 30.0 * (i - 1) for i in range(1, TARGETS + 1)}
    return write_run(folder / "run.log", targets, run_readings(targets, CYCLES, 0.004), PVS,
                     speed=2.0, dwell=4.0)


def _best(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def main() -> None:
    import pandas as pd

    from features.readings.camonitor import parse_camonitor, read_camonitor

    channels = {"target": PVS["TGT_SET_PV"], "reference": PVS["REF_PV"],
                "test": PVS["TEST_PV"]}
    with tempfile.TemporaryDirectory() as folder:
        path = _log(Path(folder))
        size_mb = path.stat().st_size / 1e6
        jobs = {
            "pandas.read_csv": lambda: pd.read_csv(path, sep=r"\s+", header=None, dtype=str,
                                                   names=["pv", "date", "clock", "value",
                                                          "status", "severity"]),
            "parse_camonitor": lambda: parse_camonitor(path),
            "read_camonitor": lambda: read_camonitor(path, channels),
        }
        times = {name: float("inf") for name in jobs}
        for _ in range(REPEATS):
            for name, job in jobs.items():
                times[name] = min(times[name], _best(job))
        lines = len(parse_camonitor(path))
    reference = times["pandas.read_csv"]
    print(f"camonitor log: {lines:,} lines, {size_mb:.1f} MB; pandas.read_csv "
          f"{reference:.2f} s")
    for name, goal in GOALS.items():
        print(f"{name}: {times[name]:.2f} s, {times[name] / reference:.2f}x read_csv "
              f"(goal <= {goal:g}x), {lines / times[name]:,.0f} lines/s")


if __name__ == "__main__":
    main()
