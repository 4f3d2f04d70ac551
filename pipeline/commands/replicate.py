"""``backlash replicate``: the backlash paper's Figs 10, 13, 14, Table 5 and k-NN accuracy on
one data set, side by side with the paper's numbers, with and without the deviation inputs."""

from __future__ import annotations

import argparse

from pipeline.commands.common import FORMATS, zero_or_more

HELP = ("Replicate the backlash paper's results (best epoch, regression R, ANOVA Table 5, k-NN "
        "accuracy) on paired tests, with and without the deviation inputs.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="readings file with paired linear and pendulum tests")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--format", default="auto",
                        choices=FORMATS,
                        help="input layout (default: detect)")
    parser.add_argument("--truth", metavar="FILE",
                        help="twin truth table: also the k-NN accuracy the true backlash "
                             "would reach in the measured classes (the ceiling set by noise)")
    parser.add_argument("--boot", type=zero_or_more, default=100,
                        help="bootstrap resamples (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings import read_readings
    from features.table import PAPER_FEATURES, feature_table
    from pipeline.replication import comparison_rows, markdown, replicate, write_replication

    readings = read_readings(args.data, args.format)
    table = feature_table(readings, target="paper", features=list(PAPER_FEATURES))
    truth = None
    if args.truth:
        from models.evaluation import true_backlash
        from pipeline.commands.common import read_truth

        truth = true_backlash(table.meta, read_truth(args.truth), table.target_kind)
    results = replicate(table.X, table.y, table.meta, args.seed, args.boot, truth)
    paths = write_replication(results, args.out, source=str(args.data))
    print(markdown(comparison_rows(results)), file=sys.stderr)
    print(f"report: {paths['html']}", file=sys.stderr)
    return 0
