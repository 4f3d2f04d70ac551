"""``backlash train``: fit one predictor, score it, save it, log it to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_data_arguments

HELP = ("Train a backlash predictor on paired tests and save it (default: the recommended "
        "model).")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from models.registry import RECOMMENDED, names

    add_data_arguments(parser)
    parser.add_argument("--out", required=True, help="model directory to write")
    parser.add_argument("--model", metavar="NAME",
                        help=f"predictor (default: {RECOMMENDED}): {', '.join(names())}; "
                             "backlash compare lists what each does")
    parser.add_argument("--uncertainty", metavar="BUDGET.toml",
                        help="ISO/TR 230-9 uncertainty budget: score the test error against "
                             "U(B), what the measurement can resolve")


def run(args: argparse.Namespace) -> int:
    import pandas  # noqa: F401 - imported once, before the MLflow child is forked: both use it

    from pipeline import tracking
    from pipeline.background_run import BackgroundRun, BackgroundTask
    from pipeline.commands.data import data_params, readings_arg

    tracking.check_uri()
    with BackgroundRun("train", tracking.log_into, tracking.prepare_model_logging) as mlflow_run:
        from pipeline.workflows.train import train

        result = train(readings_arg(args), model=args.model, split=args.split,
                       uncertainty=args.uncertainty, **data_params(args))
        mlflow_run.start(f"train {result.model}")  # the input is valid: the run may start
        print(f"{result.n_points} backlash points, target {result.target_kind}: "
              f"{result.target_reason}", file=sys.stderr)
        model_dir = result.save(args.out)
        # A second child draws the figures while this process scores the backtest for the
        # model's record and the MLflow child logs and registers the model.
        with BackgroundTask(lambda: [str(p) for p in result.draw()]) as drawing:
            mlflow_run.log(tracking.record_data(result.tracking_record()))
            result.drawn(drawing.result())
        mlflow_run.log(tracking.record_data(result.figures_record()))
        logged = mlflow_run.finish()
    print_metrics(result.model, result.metrics, file=sys.stderr)
    print(f"model -> {model_dir}/; MLflow run {logged['run_id']}, "
          f"{tracking.REGISTERED_NAME} v{logged['version']}"
          f"{' (champion)' if logged['champion'] else ''}", file=sys.stderr)
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
        from models.evaluation import resolution_verdict

        print(f"  test |error| 95th percentile {metrics['test_abs_error_p95_um']:.3f} um, RMSE "
              f"{metrics['test_rmse_um']:.3f} um against U(B) {metrics['U_B_um']:.3f} um "
              f"(k = 2): {resolution_verdict(metrics)}", file=file)
