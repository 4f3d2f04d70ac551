"""``backlash rank``: which conditions drive backlash given the others (driver, proxy, none),
beside the paper's association views, as an HTML report logged to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import parse_features
from pipeline.commands.data import add_readings_argument
from pipeline.commands.options import zero_or_more
from pipeline.workflows.rank import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
FLAGS = {"dropcolumn": "--no-dropcolumn"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser)
    parser.add_argument("--out", required=True, help="output folder for the report")
    parser.add_argument("--model", metavar="DIR",
                        help="trained model directory; its predictor gives the permutation "
                             "importance of the association views (default: a gradient "
                             "boosting regressor fitted per cross-validation fold)")
    parser.add_argument("--json", action="store_true",
                        help="print the ranking as JSON on stdout")
    parser.add_argument("--bins", default="4",
                        help="backlash classes: N quantile classes, or comma-separated class "
                             "boundaries in um such as 2,4,6 (default 4)")
    parser.add_argument("--features", help="comma-separated feature-table columns "
                                           "(default: every input the data supply)")
    parser.add_argument("--target", choices=("auto", "paper", "iso"),
                        help="backlash definition (default: the model's, else auto)")
    parser.add_argument("--k", type=int, default=5, help="k-NN neighbours (default 5)")
    parser.add_argument("--rank-by", choices=("consensus", "anova"), default="consensus",
                        help="order of the association views: mean rank of ANOVA, "
                             "permutation and mutual information (default), or the ANOVA "
                             "score as in the paper; the report lists drivers first either way")
    parser.add_argument("--boot", type=zero_or_more, default=200,
                        help="bootstrap resamples of the effect intervals and ANOVA spreads "
                             "(default 200)")
    parser.add_argument("--no-dropcolumn", action="store_true",
                        help="skip the drop-column importance of gradient boosting (faster)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("rank", args, "rank", data=args.data, out=args.out, format=args.format,
                     model=args.model, bins=args.bins, features=parse_features(args.features),
                     target=args.target, k=args.k, rank_by=args.rank_by, boot=args.boot,
                     dropcolumn=not args.no_dropcolumn, seed=args.seed)
    print_table(result, result.files["html"], file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
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
