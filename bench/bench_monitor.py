"""``monitor`` on the done-when traces (3 axes x 30 days, 60 s at 200 Hz a day: 1.08 million
samples in one Parquet file): samples per second per core, the time against the floor of
reading the same file with pandas (goal: within 3x), and the Dask engine's local-mode overhead
on the same traces as a partitioned dataset.

Each figure is the best of three runs after a warm-up, so imports and a loaded machine's
hiccups do not count. ``monitor`` runs on one core (one BLAS thread); ``pd.read_parquet`` may
use both.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

GOAL_RATIO = 3.0


def _best(run, repeats: int = 3, clock=time.perf_counter) -> float:
    run()
    times = []
    for _ in range(repeats):
        start = clock()
        run()
        times.append(clock() - start)
    return min(times)


def main() -> None:
    import pandas as pd

    from features.traces.io import write_dataset
    from pipeline.workflows.monitor import monitor
    from tests.independent_traces import fleet_traces

    trace, _ = fleet_traces(seed=7, days=30)
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = Path(tmp) / "fleet.parquet"
        trace.to_parquet(path, index=False)
        write_dataset(trace, Path(tmp) / "ds")
        floor = _best(lambda: pd.read_parquet(path))
        spent = _best(lambda: monitor(path))
        cpu = _best(lambda: monitor(path), clock=time.process_time)
        cpu_floor = _best(lambda: pd.read_parquet(path), clock=time.process_time)
        local = _best(lambda: monitor(Path(tmp) / "ds"))
        dask = _best(lambda: monitor(Path(tmp) / "ds", engine="dask"))
    n = len(trace)
    print(f"monitor of {n:,} samples (3 axes x 30 days, one Parquet file): {spent:.2f} s, "
          f"{n / cpu:,.0f} samples/s per core (processor time); pd.read_parquet floor "
          f"{floor:.2f} s, ratio {spent / floor:.1f} in wall time, {cpu / cpu_floor:.1f} in "
          f"processor time (goal < {GOAL_RATIO:.0f})")
    print(f"the same as a dataset of 90 partitions: in-process {local:.2f} s, Dask local mode "
          f"{dask:.2f} s (overhead {dask - local:+.2f} s, {(dask - local) / 90 * 1e3:+.1f} ms "
          "per partition)")


if __name__ == "__main__":
    main()
