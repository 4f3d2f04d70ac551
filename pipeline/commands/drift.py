"""``backlash drift``: backlash across maintenance visits, trend, change points, forecast."""

from __future__ import annotations

import argparse
import math
import os

from features.readings.errors import InputError
from pipeline.commands.common import FORMATS

HELP = ("Follow backlash across maintenance visits: robust trend, change points, the date it "
        "crosses a threshold, and (with --model) residual and input drift of a trained model. "
        "Exit 3 when an alert fires.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
ALERT_EXIT = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="readings file with several visits (visit, started_at)")
    parser.add_argument("--out", required=True, help="output folder for the report")
    parser.add_argument("--threshold-um", type=float, metavar="X",
                        help="backlash limit [um]: forecast the date it is crossed")
    parser.add_argument("--model", metavar="DIR",
                        help="trained model directory: monitor its residuals and inputs")
    parser.add_argument("--warn-months", type=float, default=6.0,
                        help="alert when the crossing may come within this many months of "
                             "the last visit (default 6)")
    parser.add_argument("--alpha", type=float, default=0.05,
                        help="significance level of trend tests and intervals (default 0.05)")
    parser.add_argument("--min-jump-sigma", type=float, default=3.0,
                        help="a change point must move the level by this many standard "
                             "errors (default 3)")
    parser.add_argument("--json", action="store_true", help="print the series as JSON")
    parser.add_argument("--format", default="auto",
                        choices=FORMATS,
                        help="input layout (default: detect)")


def check_options(args) -> None:
    """Every number must be finite and in range (inf and nan are refused, not propagated)."""
    if args.threshold_um is not None and not 0 < args.threshold_um < math.inf:
        raise InputError(f"--threshold-um must be a positive finite number [um], got "
                         f"{args.threshold_um:g}")
    if not 0 < args.alpha < 0.5:
        raise InputError(f"--alpha must lie in (0, 0.5), got {args.alpha:g}")
    if not 0 < args.min_jump_sigma < math.inf:
        raise InputError(f"--min-jump-sigma must be a positive finite number, got "
                         f"{args.min_jump_sigma:g}")
    if not 0 <= args.warn_months < math.inf:
        raise InputError(f"--warn-months must be a finite number of months, zero or more, got "
                         f"{args.warn_months:g}")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings import read_readings
    from features.readings.fileio import clean_nan, dumps
    from features.visits import SERIES_KEYS, visit_backlash
    from models import drift, monitoring
    from pipeline import tracking
    from pipeline.drift_report import write_drift_report

    check_options(args)
    tracking.check_uri()
    model = None
    if args.model is not None:
        from models.registry import load_model

        model = load_model(args.model)
    readings = read_readings(args.data, args.format)
    visits = visit_backlash(readings)
    counts = visits.groupby(list(SERIES_KEYS)).size()
    notes = [f"{m} axis {a}: a single visit, no drift analysis"
             for (m, a), c in counts.items() if c < 2]
    series = [drift.analyse_series(g, threshold_um=args.threshold_um, alpha=args.alpha,
                                   min_jump_sigma=args.min_jump_sigma,
                                   warn_months=args.warn_months)
              for _, g in visits.groupby(list(SERIES_KEYS), sort=True) if len(g) >= 2]
    if model is not None:
        drift.attach_model(series, monitoring.monitor_model(model, readings))
    paths = write_drift_report(series, args.out, source=str(args.data), notes=notes)
    log_to_mlflow(series, paths, args, readings)

    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    print_summary(series, paths["html"], file=sys.stderr)
    if args.json:
        print(dumps(clean_nan({"series": [s.to_json() for s in series]})))
    return ALERT_EXIT if any(s.alerts for s in series) else 0


def log_to_mlflow(series, paths, args, readings) -> None:
    """One MLflow run in experiment ``drift``: options, per-series figures, the report files."""
    from pipeline import tracking

    with tracking.run("drift", f"drift {os.path.basename(str(args.data))}"):
        mlflow = tracking.mlflow_module()
        mlflow.log_params(tracking.params({
            "data": str(args.data), "data_sha256": tracking.data_hash(readings),
            "threshold_um": args.threshold_um, "model": args.model or "",
            "alpha": args.alpha, "min_jump_sigma": args.min_jump_sigma,
            "warn_months": args.warn_months, "n_series": len(series),
        }))
        metrics = {"n_alerts": float(sum(len(s.alerts) for s in series))}
        for s in series:
            key = f"{s.machine_id}_{s.axis}"  # any id: tracking.metrics makes valid names
            metrics[f"backlash_um_{key}"] = float(s.visits["backlash_um"].iloc[-1])
            metrics[f"slope_um_per_month_{key}"] = s.trend.get("slope", float("nan"))
            metrics[f"n_change_points_{key}"] = float(len(s.change_points))
        mlflow.log_metrics(tracking.metrics(metrics))
        for path in paths.values():
            mlflow.log_artifact(str(path), artifact_path="drift")



def print_summary(series, html_path, file) -> None:
    print(f"{'machine':<12} {'axis':<4} {'visits':>6} {'last um':>8} {'slope um/mo':>12} "
          f"{'changes':>7}  crossing", file=file)
    for s in series:
        j = s.to_json()
        slope = j["slope_um_per_month"]
        print(f"{s.machine_id:<12} {s.axis:<4} {len(j['visits']):>6} {j['backlash_um'][-1]:>8.3f} "
              f"{slope if slope is not None else float('nan'):>12.4f} "
              f"{len(j['change_points']):>7}  {j['threshold_crossing'] or '-'}", file=file)
        for a in s.alerts:
            print(f"  ALERT {a['kind']}: {a['message']}", file=file)
    print(f"report: {html_path}", file=file)
