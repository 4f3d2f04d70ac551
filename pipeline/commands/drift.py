"""``backlash drift``: backlash across maintenance visits, trend, change points, forecast."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.results import ALERT_EXIT
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "drift")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the series)")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("drift", args)  # without --out or --json: the table alone, as fleet
    print_summary(result.forecasts, result.files.get("html"), file=sys.stderr)
    if args.json:
        print(result.to_json())
    return ALERT_EXIT if result.alerts else 0


def print_summary(forecasts, html_path, file) -> None:
    """One line per analysed axis (``models.condition.maintenance.AxisForecast``; with a
    budget also the last visit's U), its alerts and the changes within the measurement
    uncertainty."""
    from models.condition.drift import WITHIN_KINDS

    budget = any(f.series.coverage_factor is not None for f in forecasts)
    print(f"{'machine':<12} {'axis':<4} {'unit':<6} {'visits':>6} {'backlash':>9} "
          + (f"{'U':>6} " if budget else "")
          + f"{'target':>6} {'slope /mo':>12} {'changes':>7}  crossing", file=file)
    for f in forecasts:
        s, j = f.series, f.to_dict()
        slope = j["slope_um_per_month"]
        kind = (j.get("target_kind") or ["-"])[-1]
        u = f"{j['backlash_U_um'][-1]:>6.2f} " if budget else ""
        print(f"{s.machine_id:<12} {s.axis:<4} {s.unit:<6} {len(j['visits']):>6} "
              f"{j['backlash_um'][-1]:>9.3f} {u}{kind:>6} "
              f"{slope if slope is not None else float('nan'):>12.4f} "
              f"{len(j['change_points']):>7}  {j['threshold_crossing'] or '-'}", file=file)
        for a in s.alerts:
            print(f"  ALERT {a['kind']}: {a['message']}", file=file)
        for w in s.within_uncertainty:
            print(f"  within the measurement uncertainty: {WITHIN_KINDS[w['kind']]} of "
                  f"{w['jump_um']:+.2f} {s.unit} at visit {w['visit']} (U = {w['U_um']:.2f} "
                  f"{s.unit})",
                  file=file)
    if html_path is not None:
        print(f"report: {html_path}", file=file)
