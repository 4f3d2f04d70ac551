"""``backlash rank``: which conditions drive backlash given the others (driver, proxy, none),
beside the paper's association views, as an HTML report logged to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "rank")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the ranking)")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("rank", args, "rank")
    print_table(result, result.files["html"], file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0


def print_table(result, html_path, file) -> None:
    t = result.table
    knn = result.knn
    drivers = ", ".join(t.loc[n, "label"] for n in result.drivers()) or "none measurable"
    print(f"drivers given the other inputs: {drivers}", file=file)
    print(f"{'input':<20} {'verdict':<9} {f'effect [{result.unit}] (95 %)':<22} "
          f"{'stands in for':<16} "
          f"{'ANOVA -ln(p)':>12}", file=file)
    for name, r in t.iterrows():
        effect = (f"{r['effect_um']:.2f} ({r['effect_low_um']:.2f}-{r['effect_high_um']:.2f})"
                  if r["effect_um"] == r["effect_um"] else "n/a")
        proxy = r["proxy_for"] if isinstance(r["proxy_for"], str) else ""
        print(f"{name:<20} {r['verdict']:<9} {effect:<22} {proxy:<16} "
              f"{r['anova_score']:>12.3f}", file=file)
    print(f"association (paper's views): weighted k-NN validation accuracy "
          f"{100 * knn.accuracy:.1f} +- {100 * knn.accuracy_std:.1f} % ({knn.n_splits}-fold, "
          f"k = {knn.n_neighbors}, {len(knn.class_counts)} classes)", file=file)
    print(f"report: {html_path}", file=file)
