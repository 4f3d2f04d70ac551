"""``backlash hidden-effects``: the discovery workflow's benchmark on twin data with hidden
effects, null, confounded and aliased scenarios; score table logged to MLflow."""

from __future__ import annotations

import argparse
import sys

HELP = "Benchmark the missing-effect workflow on twin data in which effects were hidden."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder for the scenario table")
    parser.add_argument("--seeds", type=int, default=2, help="seeds per design (default 2)")
    parser.add_argument("--json", action="store_true", help="print the score as JSON")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from tqdm import tqdm

    from features.readings.errors import InputError
    from features.readings.fileio import atomic_path, clean_nan, dumps, write_json
    from models import hidden_effects
    from pipeline import tracking

    if args.seeds < 1:
        raise InputError("--seeds must be at least 1", column="--seeds")
    scenarios = hidden_effects.scenarios(tuple(range(1, args.seeds + 1)))
    table = hidden_effects.run(scenarios, progress=lambda s: tqdm(
        s, desc="scenarios", file=sys.stderr, leave=False))
    score = hidden_effects.score(table)
    out = Path(args.out)
    with atomic_path(out / "scenarios.csv") as tmp:
        table.to_csv(tmp, index=False)
    write_json(out / "score.json", score)
    with tracking.run("hidden-effects", "hidden-effect benchmark"):
        import mlflow

        mlflow.log_metrics(score)
        mlflow.log_artifact(str(out / "scenarios.csv"))
        mlflow.log_artifact(str(out / "score.json"))
    summary = table.groupby(["kind", "outcome"]).size().unstack(fill_value=0)
    print(summary.to_string(), file=sys.stderr)
    print(f"named correctly {score['named_correctly']}/{score['hidden_scenarios']} "
          f"({score['named_correctly_pct']:.0f} %), wrong {score['wrong']}, false names on nulls "
          f"{score['false_names_on_nulls']}, confident wrong on confounded/aliased "
          f"{score['confident_wrong_on_confounded_or_aliased']}; mean gap shrink "
          f"{score['mean_gap_shrink']:.2f}x, largest gap after / noise "
          f"{score['max_gap_after_over_noise']:.2f}, slowest scenario "
          f"{score['max_seconds_per_scenario']:.2f} s", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan(score)))
    return 0
