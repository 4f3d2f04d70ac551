"""``backlash rank``: which conditions drive backlash given the others (driver, proxy, none),
beside the paper's association views, as an HTML report logged to MLflow."""

from __future__ import annotations

import argparse
import os

from features.readings.errors import InputError
from pipeline.commands.common import FORMATS, parse_features, zero_or_more

HELP = ("Which inputs drive backlash given the others (driver with its effect in um, proxy, "
        "none), beside the paper's association views (weighted k-NN, ANOVA -ln(p), "
        "permutation importance, mutual information); writes an HTML report.")
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="readings file: CSV, Parquet, paper Table-2 CSV or ecmc .dat")
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
    parser.add_argument("--format", default="auto",
                        choices=FORMATS,
                        help="input layout (default: detect)")


def parse_bins(text: str):
    """``"4"`` -> 4 quantile classes; ``"2,4.5"`` -> class boundaries [um]."""
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    try:
        if len(parts) == 1 and parts[0].lstrip("+").isdigit():
            bins = int(parts[0])
            if bins < 2:
                raise InputError(f"--bins must be at least 2, got {bins}")
            return bins
        return [float(p) for p in parts] or _bad_bins(text)
    except ValueError:
        return _bad_bins(text)


def _bad_bins(text):
    raise InputError(f"--bins expects a class count such as 4 or boundaries in um such as "
                     f"2,4,6; got {text!r}")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings import read_readings
    from features.readings.fileio import clean_nan, dumps
    from features.table import feature_table
    from models.influence import explain
    from pipeline import tracking
    from pipeline.rank_report import write_rank_report

    tracking.check_uri()
    bins = parse_bins(args.bins)
    features = parse_features(args.features)
    model, notes = load_predictor(args.model)
    if model is not None and features is None:
        features = list(model.feature_names_)
    target = args.target or (model.target_kind if model is not None else "auto")

    readings = read_readings(args.data, args.format)
    table = feature_table(readings, target=target, features=features)
    if model is not None:
        missing = [f for f in model.feature_names_ if f not in table.X.columns]
        if missing:
            raise InputError(f"the model needs input {missing[0]!r}, which --features leaves "
                             "out", file=args.model)
        notes.append("permutation importance of the given trained model, scored on these "
                     "data; if the model was trained on them, the scores are optimistic")
    else:
        notes.append("no --model given: a gradient boosting regressor was fitted per "
                     "cross-validation fold for the permutation importance")
    if table.reason:
        notes.append(f"backlash target {table.target_kind}: {table.reason}")
    if _visits(table.meta) is None:
        notes.append("a single visit: no input can be told apart from the visit, and "
                     "operating hours cannot be tested")

    result = explain(table.X, table.y, table.meta, bins=bins, n_neighbors=args.k,
                     estimator=model, prefit=model is not None, rank_by=args.rank_by,
                     n_boot=args.boot, dropcolumn=not args.no_dropcolumn,
                     random_state=args.seed, source=str(args.data))
    result.notes.extend(notes)
    paths = write_rank_report(result, args.out, source=str(args.data),
                              target_kind=table.target_kind)
    log_to_mlflow(result, paths, args, table, readings)

    print_table(result, paths["html"], file=sys.stderr)
    if args.json:
        print(dumps(clean_nan(result.to_json())))
    return 0


def load_predictor(directory):
    """The trained model of ``--model`` (``models.registry.load_model``), or None."""
    if directory is None:
        return None, []
    from models.registry import load_model

    return load_model(directory), []


def _visits(meta):
    if "visit" not in meta or meta["visit"].nunique(dropna=True) < 2:
        return None
    return meta["visit"].astype(str).to_numpy()


def log_to_mlflow(result, paths, args, table, readings) -> None:
    """One MLflow run in experiment ``rank``: parameters, every score as a metric, the files."""
    from pipeline import tracking

    t = result.table
    with tracking.run("rank", f"rank {os.path.basename(str(args.data))}"):
        mlflow = tracking.mlflow_module()
        mlflow.log_params(tracking.params({
            "data": str(args.data), "data_sha256": tracking.data_hash(readings),
            "n_points": result.n_points, "features": ",".join(t.index),
            "bins": args.bins, "k": args.k, "rank_by": result.ranking.rank_by, "seed": args.seed,
            "boot": args.boot,
            "target_kind": table.target_kind, "model": args.model or "",
            "permutation_model": result.ranking.permutation_model[:500],
        }))
        metrics = {"knn_accuracy": result.knn.accuracy,
                   "knn_accuracy_std": result.knn.accuracy_std,
                   "n_drivers": float(len(result.drivers()))}
        for name, row in t.iterrows():
            metrics.update({f"driver_{name}": float(row["verdict"] == "driver"),
                            f"effect_um_{name}": row["effect_um"],
                            f"effect_low_um_{name}": row["effect_low_um"],
                            f"effect_high_um_{name}": row["effect_high_um"],
                            f"anova_score_{name}": row["anova_score"],
                            f"anova_score_std_{name}": row["anova_score_std"],
                            f"permutation_um_{name}": row["permutation_um"],
                            f"mutual_info_{name}": row["mutual_info"],
                            f"knn_drop_{name}": row["knn_drop"],
                            f"rank_{name}": float(row["rank"])})
        mlflow.log_metrics(tracking.metrics(metrics))
        for path in paths.values():
            mlflow.log_artifact(str(path), artifact_path="rank")


def print_table(result, html_path, file) -> None:
    t = result.table
    knn = result.knn
    drivers = ", ".join(t.loc[n, "label"] for n in result.drivers()) or "none measurable"
    print(f"drivers given the other inputs: {drivers}", file=file)
    print(f"{'input':<20} {'verdict':<9} {'effect [um] (95 %)':<22} {'stands in for':<16} "
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
