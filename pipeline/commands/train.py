"""``backlash train``: fit one predictor, score it, save it, log it to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP

REGISTERED_NAME = "backlash-predictor"  # pipeline.tracking.runs.REGISTERED_NAME

def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "train")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job

    result = run_job("train", args)
    print(f"{result.n_points} backlash points, target {result.target_kind}: "
          f"{result.target_reason}", file=sys.stderr)
    print_metrics(result.model, result.metrics, file=sys.stderr)
    logged = result.tracking
    tracked = (f"; MLflow run {logged['run_id']}, {REGISTERED_NAME} v{logged['version']}"
               f"{' (champion)' if logged['champion'] else ''}" if logged else "")
    print(f"model -> {result.files['model']}/{tracked}", file=sys.stderr)
    if args.json:

        print(result.to_json())
    return 0


def print_metrics(name: str, metrics: dict, file) -> None:
    line = (f"{name}: test RMSE {metrics['test_rmse_um']:.3f} um, MAE {metrics['test_mae_um']:.3f}"
            f" um, R^2 {metrics['test_r2']:.3f}, MAPE {metrics['test_mape_pct']:.1f} %")
    if "truth_rmse_um" in metrics:
        line += f"; RMSE vs true backlash {metrics['truth_rmse_um']:.3f} um"
    if "noise_floor_um" in metrics:
        line += f" (noise floor of one target {metrics['noise_floor_um']:.3f} um)"
    print(line, file=file)
    if "test_rmse_arcsec" in metrics:  # a fleet of linear and rotary axes: scored per unit
        print(f"  rotary axes: test RMSE {metrics['test_rmse_arcsec']:.3f} arcsec, MAE "
              f"{metrics['test_mae_arcsec']:.3f} arcsec, R^2 {metrics['test_r2_rotary']:.3f} "
              "(the line above: linear axes)", file=file)
    if "U_B_um" in metrics:
        from models.estimators.evaluation import resolution_verdict

        print(f"  test |error| 95th percentile {metrics['test_abs_error_p95_um']:.3f} um, RMSE "
              f"{metrics['test_rmse_um']:.3f} um against U(B) {metrics['U_B_um']:.3f} um "
              f"(k = 2): {resolution_verdict(metrics)}", file=file)
