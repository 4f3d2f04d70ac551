"""``backlash compare``: every predictor on the same split, one table, logged to MLflow."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from pipeline.commands.common import add_data_arguments

HELP = "Train every predictor (network, physics baselines, comparators) on one split; compare."
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
COLUMNS = ("model", "test_rmse_um", "test_mae_um", "test_r2", "test_mape_pct", "truth_rmse_um")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_data_arguments(parser)
    for action in parser._actions:  # compare alone also backtests (rolling origin)
        if action.dest == "split":
            action.choices = (*action.choices, "backtest")
            action.help += "; or backtest: train on visits <= k, forecast visit k + 1, every k"
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
    if args.split == "backtest":
        return run_backtest(args, names, readings, table, floor, truth)
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
                    fit, model_dir, write_figures(fit, model_dir / model_tracking.FIGURES),
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


BACKTEST_COLUMNS = ("model", "origins", "rmse_um", "truth_rmse_um", "coverage_pct",
                    "truth_coverage_pct", "skill_vs_persistence")


def run_backtest(args, names, readings, table, floor, truth) -> int:
    """Rolling-origin backtest of every predictor against persistence; tables, the wear-rate
    map of the wear map on all visits, all logged to MLflow."""
    import pandas as pd
    from tqdm import tqdm

    from features.readings.fileio import atomic_path, clean_nan, dumps
    from models import backtest
    from models.training import visit_series
    from pipeline import tracking

    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="backlash-backtest-"))
    visits, why_not = visit_series(readings)
    if visits is None:
        print(f"note: adjustments from operating hours and events only; {why_not}",
              file=sys.stderr)
    results = backtest.backtest(table, names, truth, args.seed,
                                progress=lambda s: tqdm(s, desc="origins", file=sys.stderr,
                                                        leave=False), visits=visits)
    summary = backtest.summary(results)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "backtest.csv") as tmp:
        results.to_csv(tmp, index=False)
    with atomic_path(out / "backtest_summary.csv") as tmp:
        summary.to_csv(tmp, index=False)
    figure = write_wear_map(table, out, readings) if "wear-map" in names else None
    with tracking.run("compare", f"backtest {Path(args.data).name}") as parent:
        import mlflow

        mlflow.log_params({"data": str(args.data), "data_sha256": tracking.data_hash(readings),
                           "split": "backtest", "target_kind": table.target_kind,
                           "seed": args.seed, "models": ",".join(names),
                           "noise_floor_um": floor})
        for row in summary.to_dict("records"):
            mlflow.log_metrics({f"{row['model']}_{k}": float(v) for k, v in row.items()
                                if k != "model" and pd.notna(v)})
        for name in ("backtest.csv", "backtest_summary.csv", "wear_map.csv"):
            if (out / name).is_file():
                mlflow.log_artifact(str(out / name))
        if figure:
            mlflow.log_artifact(str(figure))
    cols = [c for c in BACKTEST_COLUMNS if c in summary]
    print(f"{len(table.y)} points, target {table.target_kind}; noise floor of one measured "
          f"target {floor:.3f} um; forecast of the next visit from every earlier origin",
          file=sys.stderr)
    print(summary[cols].to_string(index=False, float_format=lambda v: f"{v:.3f}"),
          file=sys.stderr)
    print(f"best forecast: {summary.iloc[0]['model']}; MLflow run {parent.info.run_id}; tables "
          f"-> {out / 'backtest_summary.csv'}", file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"target_kind": table.target_kind, "noise_floor_um": floor,
                               "split": "backtest", "models": summary.to_dict("records"),
                               "origins": results.to_dict("records")})))
    return 0


def write_wear_map(table, out: Path, readings=None):
    """The wear map fitted on the visits since the last adjustment: w(x) with its interval
    (CSV and PNG); None when the data cannot give a wear rate (one visit)."""
    from features.readings.fileio import atomic_path
    from models.training import since_adjustment
    from models.wear_map import WearMap, epoch_lines

    kept, note = since_adjustment(table, readings)
    for line in epoch_lines(note["series"]):
        print(f"note: {line}", file=sys.stderr)
    model = WearMap().fit(kept.X, kept.y)
    if not model.can_forecast_:
        return None
    wear = model.wear_rate_map()
    with atomic_path(out / "wear_map.csv") as tmp:
        wear.to_csv(tmp, index=False)
    return plot_wear_map(wear, out / "wear_map.png")


def plot_wear_map(wear, path):
    """Wear rate along the screw [um per 1000 h] with its 95 % band."""
    from pipeline.report_page import new_figure, save_figure

    fig = new_figure(6.5, 3.2)
    ax = fig.subplots()
    ax.fill_between(wear["position_mm"], wear["wear_rate_low"], wear["wear_rate_high"],
                    alpha=0.3, label="95 % interval")
    ax.plot(wear["position_mm"], wear["wear_rate_um_per_1000h"], label="wear rate w(x)")
    ax.set_xlabel("position [mm]")
    ax.set_ylabel("wear rate [um / 1000 h]")
    ax.set_title("Where the screw wears, and how fast")
    ax.legend(loc="best")
    return save_figure(fig, path)
