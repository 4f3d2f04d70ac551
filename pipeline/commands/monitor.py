"""``backlash monitor``: lost motion per machine axis and day from dual-feedback traces."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.results import ALERT_EXIT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "monitor")
    parser.add_argument("--json", action="store_true", help="print the axes as JSON")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("monitor", args)
    print_summary(result, file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(result.to_json())
    return ALERT_EXIT if result.alerts else 0


def print_summary(result, file) -> None:
    """One line per axis: days, the last day's lost motion, change points, slope, alerts."""
    for a in result.axes:
        known = a.days.dropna(subset=["lost_motion_um"])
        last = (f"{known.lost_motion_um.iloc[-1]:.3f} +- {known.lost_motion_u_um.iloc[-1]:.3f} "
                f"{a.unit} on {known.date.iloc[-1]}" if len(known) else "no lost motion seen")
        slope = "-" if a.slope_um_per_day is None else f"{a.slope_um_per_day:+.4f}/day"
        print(f"{a.machine_id} {a.axis}: {len(a.days)} days, {last}, change points "
              f"{', '.join(a.change_points) or 'none'}, slope {slope}", file=file)
        for alert in a.alerts:
            print(f"  alert {alert['kind']}: {alert['message']}", file=file)
    if result.files:
        print(f"-> {result.files['html']}", file=file)
