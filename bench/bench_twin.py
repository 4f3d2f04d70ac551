"""The twin: a fleet of 100 machines x 3 axes x 12 visits, the paper plan at each visit
(15.6 million readings), against the goals of 10 s and 2 GB on 2 cores; and one machine against
the fleet to show the cost per reading stays flat."""

from __future__ import annotations

import resource
import subprocess
import sys
import time

from bench import size

MACHINES, VISITS = size(100, 2), size(12, 2)
FLEET = {"fleet": {"machines": MACHINES, "axes": ["X", "Y", "Z"], "visits": VISITS}}
GOAL_S = 10.0
GOAL_GB = 2.0


def child(machines: int) -> None:
    from models.physics.campaign import simulate

    config = {"fleet": {**FLEET["fleet"], "machines": machines}}
    start = time.perf_counter()
    sim = simulate(config, seed=0)
    print(time.perf_counter() - start, len(sim.readings))


def _run(machines: int) -> tuple[float, int]:
    out = subprocess.run([sys.executable, "-c",
                          f"from bench.bench_twin import child; child({machines})"],
                         capture_output=True, text=True, check=True)
    elapsed, n = out.stdout.split()
    return float(elapsed), int(n)


def main() -> None:
    small_s, small_n = _run(1)
    fleet_s, fleet_n = _run(MACHINES)
    peak_bytes = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024  # Linux: KiB
    peak_gb = peak_bytes / 1e9
    print(f"1 machine x 3 axes x {VISITS} visits: {small_n:,} readings in {small_s:.2f} s")
    print(f"{MACHINES} machines x 3 axes x {VISITS} visits: {fleet_n:,} readings in {fleet_s:.1f} s "
          f"(goal < {GOAL_S:.0f} s, ratio {fleet_s / GOAL_S:.2f}), {fleet_n / fleet_s:,.0f} "
          f"readings/s, peak memory {peak_bytes / 1024**3:.2f} GiB = {peak_gb:.2f} GB "
          f"(goal < {GOAL_GB:g} GB, ratio {peak_gb / GOAL_GB:.2f})")
    print(f"cost per reading, fleet / single machine: "
          f"{(fleet_s / fleet_n) / (small_s / small_n):.2f}")


if __name__ == "__main__":
    main()
