"""End-to-end wall time of the everyday commands, ``backlash train`` and ``backlash predict`` of
the default predictor on the demo data, as a ratio to ``python -c "import mlflow, pandas"``
measured in the same run (best of ``REPEATS`` each, interleaved so machine load hits all
alike). ``train`` tracks into a fresh SQLite MLflow store in a temporary folder; its first run
(which creates the store) is reported apart. Also lists which heavy libraries each command
imported: a predictor that saves itself needs neither skops nor torch nor mlflow to predict.

Goals: train <= 2x the reference, predict <= 1.5x.

Start-up: ``backlash --help`` and ``backlash CMD --help`` of ``HELP_COMMANDS`` beside
``python -c pass`` (median of ``REPEATS``); goal under ``HELP_GOAL_S`` each, with no numeric
library imported.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import size, verdict

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "experiments" / "data" / "twin" / "readings.csv"
REPEATS = size(5, 1)
GOALS = {"train": 2.0, "predict": 1.5}
HEAVY = ("mlflow", "torch", "skops", "matplotlib", "optuna", "sklearn")
HELP_GOAL_S = 0.1
# small, model and large tables; a tiny run times one
HELP_COMMANDS = size(("iso", "train", "compensate", "fleet", "monitor"), ("train",))


def _env(folder: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "MLFLOW_DISABLE_TELEMETRY": "true",
            "MPLBACKEND": "Agg", "MLFLOW_TRACKING_URI": f"sqlite:///{folder / 'mlflow.db'}",
            "BACKLASH_ARTIFACTS": str(folder / "mlartifacts")}


def _timed(argv: list[str], env: dict) -> float:
    start = time.perf_counter()
    subprocess.run(argv, env=env, check=True, capture_output=True)
    return time.perf_counter() - start


def _imported(argv: list[str], env: dict) -> list[str]:
    """Top-level heavy packages the command imports (from ``python -X importtime``)."""
    err = subprocess.run([argv[0], "-X", "importtime", *argv[1:]], env=env, check=True,
                         capture_output=True, text=True).stderr
    names = {line.rsplit("|", 1)[-1].strip() for line in err.splitlines()
             if line.startswith("import time:")}
    return [h for h in HEAVY if h in names]


def startup(env: dict) -> None:
    """Median wall time of the help screens beside the bare interpreter's."""
    import statistics

    python = sys.executable
    commands = {"python -c pass": [python, "-c", "pass"],
                "backlash --help": [python, "-m", "pipeline.cli", "--help"],
                **{f"backlash {c} --help": [python, "-m", "pipeline.cli", c, "--help"]
                   for c in HELP_COMMANDS}}
    times = {name: [] for name in commands}
    for _ in range(REPEATS):
        for name, argv in commands.items():
            times[name].append(_timed(argv, env))
    print(f"{'start-up':<28} {'median [s]':>10}  goal")
    for name, argv in commands.items():
        median = statistics.median(times[name])
        goal = "" if name.startswith("python") else (
            f"< {HELP_GOAL_S:g} {verdict(median < HELP_GOAL_S)}  ")
        heavy = "" if name.startswith("python") else ", ".join(_imported(argv, env)) or "-"
        print(f"{name:<28} {median:>10.3f}  {goal}{heavy}")


def main() -> None:
    from models.serving import registry

    python = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = _env(folder)
        model, pred = folder / "model", folder / "pred.csv"
        commands = {
            "reference": [python, "-c", "import mlflow, pandas"],
            "train": [python, "-m", "pipeline.cli", "train", str(DATA), "--out", str(model)],
            "predict": [python, "-m", "pipeline.cli", "predict", str(model), str(DATA),
                        "--out", str(pred)],
        }
        first_train = _timed(commands["train"], env)
        best = {name: float("inf") for name in commands}
        for _ in range(REPEATS):
            for name, argv in commands.items():
                best[name] = min(best[name], _timed(argv, env))
        imports = {name: _imported(commands[name], env) for name in ("train", "predict")}
        startup(env)

    print(f"default predictor: {registry.RECOMMENDED}; data: {DATA.relative_to(REPO)}")
    print(f"{'command':<28} {'wall [s]':>9} {'ratio':>6}  goal   heavy imports")
    print(f"{'import mlflow, pandas':<28} {best['reference']:>9.2f} {1:>6.2f}")
    print(f"{'train (first, new store)':<28} {first_train:>9.2f} "
          f"{first_train / best['reference']:>6.2f}")
    for name in ("train", "predict"):
        ratio = best[name] / best["reference"]
        print(f"{name:<28} {best[name]:>9.2f} {ratio:>6.2f}  <= {GOALS[name]:<4} "
              f"{', '.join(imports[name]) or '-'}")


if __name__ == "__main__":
    main()
