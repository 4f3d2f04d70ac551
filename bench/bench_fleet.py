"""End-to-end wall time and peak memory of ``iso``, ``drift``, ``train`` (on the CSV) and
``fleet`` (on a store the CSV was ingested into) on the ``fleet``
preset (about 415,000 readings, a 67 MB CSV), side by side with the floor every one of them
pays: ``python -c "import mlflow, pandas; pandas.read_csv(F)"``, measured in the same run.

Each command runs ``REPEATS`` times, interleaved with the others so machine load hits all
alike; the best wall time counts. ``train`` tracks into a fresh SQLite MLflow store in a
temporary folder. Peak memory is the largest resident set of the command (its children
included, from ``os.wait4``), as a ratio to the validated readings frame in memory
(``frame.memory_usage(deep=True).sum()``), and what a job holds beyond the floor's own peak
(``above floor``: the floor itself, the libraries plus pandas' reading of the CSV, is about 5x
the frame).

Goals: every job <= 3x the floor in time, and <= 3x the frame in memory beyond the floor.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import size

REPO = Path(__file__).resolve().parents[1]
REPEATS = size(3, 1)
# overrides of the fleet preset: a tiny run simulates one axis of one machine at three visits
CAMPAIGN = size(None, '[fleet]\nmachines = 1\naxes = ["X"]\nvisits = 3\nadjust_at = []\n')
GOAL = 3.0
# Exit codes a command may end with on this data: drift exits 3 when an alert fires.
ACCEPTED = {"drift": (0, 3), "fleet": (0, 3)}


def _env(folder: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "MLFLOW_DISABLE_TELEMETRY": "true",
            "MPLBACKEND": "Agg", "MLFLOW_TRACKING_URI": f"sqlite:///{folder / 'mlflow.db'}",
            "BACKLASH_ARTIFACTS": str(folder / "mlartifacts")}


def _run(name: str, argv: list[str], env: dict, cwd: Path) -> tuple[float, float]:
    """Wall time [s] and peak resident set [bytes] of one run of ``argv``."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage, not all children's
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stderr.close()
    if proc.returncode not in ACCEPTED.get(name, (0,)):
        raise RuntimeError(f"{name} exited {proc.returncode}: {err.decode()[-2000:]}")
    return wall, usage.ru_maxrss * 1024.0  # ru_maxrss is in KiB on Linux


def simulate_fleet(folder: Path, env: dict) -> Path:
    """The fleet preset's readings CSV, simulated into ``folder``."""
    argv = [sys.executable, "-m", "pipeline.cli", "simulate", "--preset", "fleet",
            "--out", str(folder)]
    if CAMPAIGN:
        config = folder.with_suffix(".toml")
        config.write_text(CAMPAIGN)
        argv += ["--config", str(config)]
    subprocess.run(argv, env=env, check=True, capture_output=True)
    return folder / "readings.csv"


def _frame_size(data: Path, env: dict) -> tuple[int, float]:
    """Readings and bytes of the validated frame, read in a child: this process stays small,
    since a child's peak resident set starts from its parent's at the fork."""
    code = ("import sys; from features.readings.io import read_readings; "
            "f = read_readings(sys.argv[1]); print(len(f), f.memory_usage(deep=True).sum())")
    out = subprocess.run([sys.executable, "-c", code, str(data)], env=env, check=True,
                         capture_output=True, text=True).stdout.split()
    return int(out[0]), float(out[1])


def main() -> None:
    python = sys.executable
    cli = [python, "-m", "pipeline.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = _env(folder)
        data = simulate_fleet(folder / "fleet", env)
        store = folder / "store"
        subprocess.run([*cli, "ingest", str(data), "--store", str(store)], env=env, check=True,
                       capture_output=True)
        n_readings, frame_bytes = _frame_size(data, env)
        csv_bytes = data.stat().st_size
        commands = {
            "floor": [python, "-c", f"import mlflow, pandas; pandas.read_csv({str(data)!r})"],
            "iso": [*cli, "iso", str(data), "--json"],
            "drift": [*cli, "drift", str(data), "--out", str(folder / "drift")],
            "train": [*cli, "train", str(data), "--model", "wear-map",
                      "--out", str(folder / "model")],
            # the fleet view reads the store the readings were ingested into
            "fleet": [*cli, "fleet", str(store), "--threshold-um", "4", "--out",
                      str(folder / "site"), "--json"],
        }
        best = {name: float("inf") for name in commands}
        peak = dict.fromkeys(commands, 0.0)
        for _ in range(REPEATS):
            for name, argv in commands.items():
                wall, rss = _run(name, argv, env, folder)
                best[name] = min(best[name], wall)
                peak[name] = max(peak[name], rss)

    print(f"fleet preset: {n_readings:,} readings, CSV {csv_bytes / 1e6:.0f} MB, readings frame "
          f"{frame_bytes / 1e6:.0f} MB in memory; best of {REPEATS}")
    print(f"{'job':<8} {'wall [s]':>9} {'x floor':>8} {'goal':>6} {'peak RSS [MB]':>14} "
          f"{'x frame':>8} {'above floor':>12}")
    for name in commands:
        ratio = best[name] / best["floor"]
        goal = "-" if name == "floor" else f"<= {GOAL:g}"
        above = (peak[name] - peak["floor"]) / frame_bytes
        print(f"{name:<8} {best[name]:>9.2f} {ratio:>8.2f} {goal:>6} {peak[name] / 1e6:>14.0f} "
              f"{peak[name] / frame_bytes:>8.1f} {above:>11.1f}x")


if __name__ == "__main__":
    main()
