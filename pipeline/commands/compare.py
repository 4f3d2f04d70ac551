"""``backlash compare``: every predictor on the same split, one table, logged to MLflow."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from pipeline.commands.common import add_data_arguments

HELP = "Train every predictor (network, physics baselines, comparators) on one split; compare."
COLUMNS = ("model", "test_rmse_um", "test_mae_um", "test_r2", "test_mape_pct", "truth_rmse_um")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_data_arguments(parser)
    parser.add_argument("--models", help="comma-separated predictor names (default: all)")
    parser.add_argument("--out", help="folder for the comparison table and figures")
    parser.add_argument("--json", action="store_true", help="print the table as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    import pandas as pd
    from tqdm import tqdm

    from features.readings.fileio import atomic_path, clean_nan, dumps
    from models import registry
    from models.training import fit_model
    from pipeline import model_tracking, tracking
    from pipeline.commands.common import load_table, parse_features
    from pipeline.model_report import write_figures

    tracking.check_uri()
    names = parse_features(args.models) or registry.names()  # same list syntax as --features
    for name in names:
        registry.check_name(name)
    readings, table, floor, truth = load_table(args)
    digest = tracking.data_hash(readings)
    rows, fits = [], {}
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="backlash-compare-"))
    with tracking.run("compare", f"compare {Path(args.data).name}") as parent:
        mlflow = tracking.mlflow_module()
        mlflow.log_params(tracking.params({
            "data": str(args.data), "data_sha256": digest, "split": args.split,
            "target_kind": table.target_kind, "seed": args.seed, "models": ",".join(names),
            "noise_floor_um": floor}))
        for name in tqdm(names, desc="models", file=sys.stderr, leave=False):
            fit = fit_model(table, name, args.split, args.seed, truth, floor, str(args.data))
            fits[name] = fit
            model_dir = registry.save_model(fit.trained_model({"data_sha256": digest}),
                                            out / "models" / name)
            with tracking.run("compare", name, nested=True):
                version = model_tracking.log_fit(
                    fit, model_dir, write_figures(fit, model_dir / "figures"),
                    {"model": name, "split": args.split, "data_sha256": digest,
                     "target_kind": table.target_kind, "seed": args.seed})
            rows.append({"model": name, **fit.metrics, "version": version})
        result = pd.DataFrame(rows).sort_values("test_rmse_um", kind="stable")
        best = result.iloc[0]
        champion = model_tracking.promote_if_best(best["version"], digest, best["test_rmse_um"])
        with atomic_path(out / "comparison.csv") as tmp:
            result.to_csv(tmp, index=False)
        mlflow.log_artifact(str(out / "comparison.csv"))
        mlflow.log_metrics(tracking.metrics({f"{r['model']}_test_rmse_um": r["test_rmse_um"]
                                             for r in rows}))
    print_table(result, floor, table, file=sys.stderr)
    print(f"best: {best['model']}{' (now champion)' if champion else ''}; MLflow run "
          f"{parent.info.run_id}; table -> {out / 'comparison.csv'}", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"target_kind": table.target_kind, "noise_floor_um": floor,
                               "models": result.drop(columns="version").to_dict("records")})))
    return 0


def print_table(result, floor: float, table, file) -> None:
    cols = [c for c in COLUMNS if c in result]
    print(f"{len(table.y)} points, target {table.target_kind}; noise floor of one measured "
          f"target {floor:.3f} um", file=file)
    print(result[cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"), file=file)
