"""Wall time of ``backlash ingest`` of the ``fleet`` preset (about 415,000 readings, a 67 MB
CSV) into a new embedded store, side by side with ``backlash convert`` of the same file (to
CSV and to Parquet), measured in the same run; also a second ingest of the same file (every
test already stored: nothing written) and reading the whole store back
(``backlash convert STORE --out F.parquet``).

Each command runs ``REPEATS`` times, interleaved with the others so machine load hits all
alike; the best wall time counts. Every ingest writes a new store.

Goal: ingest <= 2x convert (the faster of the two conversions).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import size
from bench.bench_fleet import simulate_fleet

REPO = Path(__file__).resolve().parents[1]
REPEATS = size(3, 1)
GOAL = 2.0


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "MLFLOW_DISABLE_TELEMETRY": "true"}


def _run(argv: list[str], env: dict) -> float:
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv[3:5])} exited {done.returncode}: "
                           f"{done.stderr[-2000:]}")
    return wall


def main() -> None:
    cli = [sys.executable, "-m", "pipeline.cli"]
    env = _env()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        data = str(simulate_fleet(folder / "fleet", env))
        kept = str(folder / "kept")
        subprocess.run([*cli, "ingest", data, "--store", kept], env=env, check=True,
                       capture_output=True)
        commands = {
            "convert -> csv": lambda i: [*cli, "convert", data, "--out", f"{tmp}/c{i}.csv"],
            "convert -> parquet": lambda i: [*cli, "convert", data, "--out",
                                             f"{tmp}/c{i}.parquet"],
            "ingest (new store)": lambda i: [*cli, "ingest", data, "--store", f"{tmp}/s{i}"],
            "ingest (all stored)": lambda i: [*cli, "ingest", data, "--store", kept],
            "read store -> parquet": lambda i: [*cli, "convert", kept, "--out",
                                                f"{tmp}/r{i}.parquet"],
        }
        best = dict.fromkeys(commands, float("inf"))
        for i in range(REPEATS):
            for name, argv in commands.items():
                best[name] = min(best[name], _run(argv(i), env))

    floor = min(best["convert -> csv"], best["convert -> parquet"])
    print(f"fleet preset CSV ({Path(data).name}), best of {REPEATS}; x convert = wall / the "
          f"faster convert ({floor:.2f} s)")
    print(f"{'command':<24} {'wall [s]':>9} {'x convert':>10} {'goal':>7}")
    for name, wall in best.items():
        goal = f"<= {GOAL:g}" if name == "ingest (new store)" else "-"
        print(f"{name:<24} {wall:>9.2f} {wall / floor:>10.2f} {goal:>7}")


if __name__ == "__main__":
    main()
