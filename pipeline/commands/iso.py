"""``backlash iso``: ISO 230-2 figures of every test in a readings file."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.common import FORMATS

HELP = "ISO 230-2 analysis: per-target and axis figures (A, E, M, R, B) of every test."
OUTPUTS = {"plot": "file"}  # output paths by argparse dest: checked before any work
JSON_KEYS = ("machine_id", "axis", "visit", "test_id", "unit", "A", "A_up", "A_down", "E",
             "E_up", "E_down", "M", "R", "R_up", "R_down", "B", "B_mean")
PER_TARGET_KEYS = ("target", "mean_up", "mean_down", "s_up", "s_down", "B_i", "R_i")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="readings file: CSV, Parquet, paper Table-2 CSV or ecmc .dat")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="input layout (default: detect)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object per test on stdout")
    parser.add_argument("--plot", metavar="OUT.png", help="write the ISO chart (one panel per test)")
    parser.add_argument("--drop-outliers", action="store_true",
                        help="leave flagged outlier readings out of the figures")


def run(args: argparse.Namespace) -> int:
    from features import iso230
    from features.readings import read_readings
    from features.readings.errors import InputError
    from features.readings.fileio import clean_nan, dumps

    if args.plot and not args.plot.lower().endswith(".png"):
        raise InputError("expected a .png file name", column="--plot", file=args.plot)
    readings = read_readings(args.file, args.format)
    flagged = iso230.outliers(readings)
    _report_outliers(readings.loc[flagged], args.drop_outliers)
    if args.drop_outliers:
        readings = readings.loc[~flagged]
    targets = iso230.per_target(readings)
    figures = iso230.axis_figures(readings, targets)
    if args.plot:
        from pipeline.iso_chart import MAX_PANELS, plot_tests

        if len(figures) > MAX_PANELS:
            raise InputError(f"--plot draws at most {MAX_PANELS} tests, the file has "
                             f"{len(figures)}; split it first", file=args.file)
        plot_tests(targets, figures, args.plot)
    _print_table(figures)
    if args.json:
        print(dumps(clean_nan(as_json(targets, figures))))
    return 0


def as_json(targets, figures) -> list[dict]:
    """One object per test with the public keys (figures in um, arcsec for rotary axes)."""
    keys = ["machine_id", "axis", "visit", "test_id"]
    per_test = {k: g for k, g in targets.groupby(keys, sort=False)}
    out = []
    for row in figures[list(JSON_KEYS)].to_dict("records"):
        rows = per_test[tuple(row[k] for k in keys)].sort_values("target")
        row["per_target"] = rows[list(PER_TARGET_KEYS)].to_dict("records")
        out.append(row)
    return out


def _print_table(figures) -> None:
    columns = ["test_id", "unit", "A", "E", "M", "R", "B", "B_mean"]
    print(figures[columns].to_string(index=False, float_format=lambda v: f"{v:.3f}"),
          file=sys.stderr)


def _report_outliers(rows, dropped: bool) -> None:
    action = "dropped" if dropped else "kept; --drop-outliers leaves them out"
    for r in rows.itertuples():
        print(f"outlier ({action}): test {r.test_id} target {r.target:g} direction "
              f"{r.direction} cycle {r.cycle}: deviation {r.deviation_um:.3f}", file=sys.stderr)
