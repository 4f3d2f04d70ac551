"""``backlash hidden-effects``: the discovery workflow's benchmark on twin data with hidden
effects, null, confounded and aliased scenarios (scenarios are data: a TOML file); score table
per design logged to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "hidden-effects")
    parser.add_argument("--json", action="store_true", help="print the score as JSON")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("hidden-effects", args, "scenarios")
    score = result.score
    print(result.by_design.to_string(index=False), file=sys.stderr)
    print(f"named correctly {score['named_correctly']}/{score['hidden_scenarios']} "
          f"({score['named_correctly_pct']:.0f} %), wrong {score['wrong']}, false names on nulls "
          f"{score['false_names_on_nulls']}/{score['null_scenarios']}, confounded/aliased "
          f"answered ambiguous with the separating test "
          f"{score['hard_answered_ambiguous_with_test']}/{score['hard_scenarios']}; mean gap "
          f"shrink {score['mean_gap_shrink']:.2f}x, largest gap after / noise "
          f"{score['max_gap_after_over_noise']:.2f}, slowest scenario "
          f"{score['max_seconds_per_scenario']:.2f} s CPU", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
