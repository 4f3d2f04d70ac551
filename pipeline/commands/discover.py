"""``backlash discover``: name the physical effect the simulation model is missing."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import FORMATS

HELP = ("Find where simulation and measurement disagree, name the missing physical effect, "
        "add it and show the gap shrink.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="readings file (columns of docs/data-contract.md; "
                                     "measured_at for time effects)")
    parser.add_argument("--baseline", default="backlash,lead_error_linear",
                        help="comma-separated effects of the simulation model "
                             "(default backlash,lead_error_linear)")
    parser.add_argument("--out", required=True, help="output folder for the report")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")


def run(args: argparse.Namespace) -> int:
    from features.readings import read_readings
    from features.readings.fileio import clean_nan, dumps
    from models.discovery import check_baseline, discover
    from pipeline import discovery_report, tracking

    tracking.check_uri()
    baseline = check_baseline(args.baseline)
    readings = read_readings(args.data, args.format)
    result = discover(readings, baseline, random_state=args.seed, source=str(args.data))
    paths = discovery_report.write(result, readings, args.out, str(args.data))
    with tracking.run("discover", f"discover {args.data}"):
        mlflow = tracking.mlflow_module()
        mlflow.log_params(tracking.params({"data": str(args.data), "baseline": ",".join(baseline),
                                           "data_sha256": tracking.data_hash(readings),
                                           "named": ",".join(result.named) or "none"}))
        mlflow.log_metrics(tracking.metrics({"rmse_before_um": result.rmse_before_um,
                                             "rmse_after_um": result.rmse_after_um,
                                             "repeatability_um": result.repeatability_um}))
        for path in paths.values():
            mlflow.log_artifact(str(path), artifact_path="discover")
    for step in result.steps:
        print(f"named {step.effect} {step.parameters}: gap {step.rmse_before_um:.3f} -> "
              f"{step.rmse_after_um:.3f} um (delta BIC {step.delta_bic:.0f}, CV gain "
              f"{100 * step.cv_gain:.0f} %)", file=sys.stderr)
    for group in result.ambiguous:
        print(f"ambiguous: {', '.join(group)}", file=sys.stderr)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"gap {result.rmse_before_um:.3f} -> {result.rmse_after_um:.3f} um, repeatability "
          f"{result.repeatability_um:.3f} um; report {paths['html']}", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan(result.to_json())))
    return 0
