"""ISO 230-2 analysis of 10,000 tests (8 targets x 5 cycles x 2 directions), in a child
process so its peak memory is measured alone; and the vectorised code against a loop that
analyses one test at a time, on the same 200 tests in the same run.

Goal: 10,000 tests in under 10 s and under 2 GB on 2 cores.
"""

from __future__ import annotations

import resource
import subprocess
import sys
import time

import numpy as np
import pandas as pd

from bench import size

TESTS, TARGETS, CYCLES = size(10_000, 50), 8, 5
SMALL = size(200, 10)  # tests analysed all at once and one at a time
GOAL_S, GOAL_GB = 10.0, 2.0


def readings(n_tests: int, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    test, target, cycle, up = (a.ravel() for a in np.meshgrid(
        np.arange(n_tests), np.linspace(0, 350, TARGETS), np.arange(1, CYCLES + 1),
        [True, False], indexing="ij"))
    b = rng.uniform(1, 5, n_tests)[test]
    return pd.DataFrame({
        "machine_id": (test // 120).astype(str), "axis": "X", "visit": (test // 10 % 12).astype(str),
        "test_id": test.astype(str), "method": "linear", "target": target,
        "direction": np.where(up, "+", "-"), "cycle": cycle,
        "deviation_um": np.where(up, -b / 2, b / 2) + rng.normal(0, 0.5, test.size)})


def _analyse(frame: pd.DataFrame):
    from features import iso230

    targets = iso230.per_target(frame)
    return iso230.axis_figures(frame, targets), iso230.outliers(frame)


def child() -> None:
    frame = readings(TESTS)
    start = time.perf_counter()
    figures, _ = _analyse(frame)
    elapsed = time.perf_counter() - start
    assert len(figures) == TESTS
    print(elapsed)


def main() -> None:
    out = subprocess.run([sys.executable, "-c", "from bench.bench_iso import child; child()"],
                         capture_output=True, text=True, check=True)
    elapsed = float(out.stdout.strip())
    peak_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024**2
    n = TESTS * TARGETS * CYCLES * 2
    print(f"ISO 230-2 of {TESTS} tests ({n} readings, with outlier flags): {elapsed:.2f} s "
          f"(goal < {GOAL_S:.0f} s, ratio {elapsed / GOAL_S:.2f}), {n / elapsed:,.0f} readings/s; "
          f"peak memory {peak_gb:.2f} GB incl. data (goal < {GOAL_GB:.0f} GB)")

    small = readings(SMALL, seed=1)
    _analyse(small)  # warm-up: imports
    start = time.perf_counter()
    _analyse(small)
    vectorised = time.perf_counter() - start
    start = time.perf_counter()
    for _, one in small.groupby("test_id"):
        _analyse(one)
    looped = time.perf_counter() - start
    print(f"{SMALL} tests: all at once {vectorised:.3f} s, one at a time {looped:.2f} s "
          f"(ratio {looped / vectorised:.0f}x)")


if __name__ == "__main__":
    main()
