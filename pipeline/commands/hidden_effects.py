"""``backlash hidden-effects``: the discovery workflow's benchmark on twin data with hidden
effects, null, confounded and aliased scenarios (scenarios are data: a TOML file); score table
per design logged to MLflow."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "Benchmark the missing-effect workflow on twin data in which effects were hidden."
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
SCENARIOS = Path(__file__).resolve().parents[2] / "experiments" / "hidden_effect_scenarios.toml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder for the scenario table")
    parser.add_argument("--scenarios", default=str(SCENARIOS),
                        help="scenario file (default experiments/hidden_effect_scenarios.toml)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="seeds per design (default: the scenario file's seeds)")
    parser.add_argument("--json", action="store_true", help="print the score as JSON")


def read_scenarios(path) -> dict:
    """The scenario specification of a TOML file (see ``models.discovery_benchmark``)."""
    from features.readings.errors import InputError
    from features.readings.fileio import read_toml

    spec = read_toml(path, "scenarios")
    unknown = set(spec) - {"baseline", "seeds", "resolution_um", "truth", "hidden", "designs",
                           "special"}
    if unknown:
        raise InputError(f"unknown key {min(unknown)!r}", file=path, column=min(unknown))
    if not spec.get("designs"):
        raise InputError("no [designs.*]: a benchmark needs at least one design", file=path)
    return spec


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from features.readings.errors import InputError
    from features.readings.fileio import atomic_path, clean_nan, dumps, write_json
    from models import discovery_benchmark
    from pipeline import tracking

    if args.seeds is not None and args.seeds < 1:
        raise InputError("--seeds must be at least 1", column="--seeds")
    spec = read_scenarios(args.scenarios)
    seeds = None if args.seeds is None else tuple(range(1, args.seeds + 1))
    try:
        scenarios = discovery_benchmark.expand(spec, seeds)
    except InputError as err:
        raise InputError(err.message, file=args.scenarios, column=err.column) from None
    table = discovery_benchmark.run(scenarios, progress=lambda s: tqdm(
        s, desc="scenarios", file=sys.stderr, leave=False))
    score = discovery_benchmark.score(table)
    by_design = discovery_benchmark.score_by_design(table)
    out = Path(args.out)
    with atomic_path(out / "scenarios.csv") as tmp:
        table.to_csv(tmp, index=False)
    with atomic_path(out / "score_by_design.csv") as tmp:
        by_design.to_csv(tmp, index=False)
    write_json(out / "score.json", score)
    with tracking.run("hidden-effects", "hidden-effect benchmark"):
        import mlflow

        mlflow.log_metrics({k: v for k, v in clean_nan(score).items() if v is not None})
        for name in ("scenarios.csv", "score_by_design.csv", "score.json"):
            mlflow.log_artifact(str(out / name))
    print(by_design.to_string(index=False), file=sys.stderr)
    print(f"named correctly {score['named_correctly']}/{score['hidden_scenarios']} "
          f"({score['named_correctly_pct']:.0f} %), wrong {score['wrong']}, false names on nulls "
          f"{score['false_names_on_nulls']}/{score['null_scenarios']}, confounded/aliased "
          f"answered ambiguous with the separating test "
          f"{score['hard_answered_ambiguous_with_test']}/{score['hard_scenarios']}; mean gap "
          f"shrink {score['mean_gap_shrink']:.2f}x, largest gap after / noise "
          f"{score['max_gap_after_over_noise']:.2f}, slowest scenario "
          f"{score['max_seconds_per_scenario']:.2f} s CPU", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan(score)))
    return 0
