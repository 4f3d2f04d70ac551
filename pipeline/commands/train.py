"""``backlash train``: fit one predictor, score it, save it, log it to MLflow."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import add_data_arguments

HELP = "Train a backlash predictor on paired tests and save it (default: the recommended model)."
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_data_arguments(parser)
    parser.add_argument("--out", required=True, help="model directory to write")
    parser.add_argument("--model", help="predictor name (default: wear-map); see backlash "
                                        "compare for the list")


def run(args: argparse.Namespace) -> int:
    import pandas  # noqa: F401 - imported once, before the MLflow child is forked: both use it

    from pipeline import tracking
    from pipeline.background_run import BackgroundRun

    tracking.check_uri()
    with BackgroundRun("train", _log_and_promote) as mlflow_run:
        return _train(args, mlflow_run)


def _train(args: argparse.Namespace, mlflow_run) -> int:
    from models import registry
    from models.training import fit_model, since_adjustment
    from pipeline import model_tracking, tracking
    from pipeline.commands.common import load_table
    from pipeline.model_report import write_figures

    name = args.model or registry.RECOMMENDED
    registry.check_name(name)
    readings, table, floor, truth = load_table(args)
    mlflow_run.start(f"train {name}")
    print(f"{len(table.y)} backlash points, target {table.target_kind}: {table.reason}",
          file=sys.stderr)
    clock = None
    if name.startswith("wear-map"):  # the wear clock restarts at a mechanical adjustment
        from models.wear_map import epoch_lines

        table, clock = since_adjustment(table, readings)
        for line in [*epoch_lines(clock["series"]), clock["change_points"]]:
            if line and line != "searched":
                print(f"note: {line}", file=sys.stderr)
    fit = fit_model(table, name, args.split, args.seed, truth, floor, str(args.data))
    digest = tracking.data_hash(readings)
    meta = {"split": args.split, "data_sha256": digest, "data": str(args.data),
            "noise_floor_um": floor, "target_reason": table.reason, "seed": args.seed,
            **({"wear_clock": clock} if clock else {})}
    model_dir = registry.save_model(fit.trained_model(meta), args.out)
    mlflow_run.log(model_tracking.fit_record(fit, model_dir, {
        "model": name, "split": args.split, "target_kind": table.target_kind,
        "features": ",".join(table.X.columns), "n_train": len(fit.train_index),
        "n_test": len(fit.test_index), "data": str(args.data), "data_sha256": digest,
        "seed": args.seed}))
    figures = write_figures(fit, model_dir / model_tracking.FIGURES)  # drawn while the model is logged
    mlflow_run.log({"figures": [str(path) for path in figures]})
    logged = mlflow_run.finish()
    print_metrics(name, fit.metrics, file=sys.stderr)
    print(f"model -> {model_dir}/; MLflow run {logged['run_id']}, "
          f"{model_tracking.REGISTERED_NAME} v{logged['version']}"
          f"{' (champion)' if logged['champion'] else ''}", file=sys.stderr)
    return 0


def _log_and_promote(record: dict) -> dict:
    """Inside the MLflow run: log a part of the fit; a model becomes champion if it is best."""
    from pipeline import model_tracking

    logged = model_tracking.log_record(record)
    if "version" in logged:
        logged["champion"] = model_tracking.promote_if_best(
            logged["version"], record["params"]["data_sha256"], record["metrics"]["test_rmse_um"])
    return logged


def print_metrics(name: str, metrics: dict, file) -> None:
    line = (f"{name}: test RMSE {metrics['test_rmse_um']:.3f} um, MAE {metrics['test_mae_um']:.3f}"
            f" um, R^2 {metrics['test_r2']:.3f}, MAPE {metrics['test_mape_pct']:.1f} %")
    if "truth_rmse_um" in metrics:
        line += f"; RMSE vs true backlash {metrics['truth_rmse_um']:.3f} um"
    if "noise_floor_um" in metrics:
        line += f" (noise floor of one target {metrics['noise_floor_um']:.3f} um)"
    print(line, file=file)
