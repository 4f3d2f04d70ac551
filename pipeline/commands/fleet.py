"""``backlash fleet``: one view of the fleet, worst first; a static site with ``--out``."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.results import ALERT_EXIT
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "fleet")
    parser.add_argument("--json", action="store_true", help=JSON_HELP + " (the axes worst "
                                                                       "first)")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("fleet", args)
    print_summary(result, file=sys.stderr)
    if args.json:
        print(result.to_json())
    return ALERT_EXIT if result.alerts else 0


def print_summary(result, file) -> None:
    """The fleet table, worst first; the last recorded forecast (mean backlash [low, high]
    and the day it is for) and compensation (day, reversal compensation) where a store holds
    them."""
    records = any(v.forecasts or v.compensations for v in result.axes)
    extra = f"  {'last forecast':<28}  {'compensated':<18}" if records else ""
    print(f"{'#':>3} {'machine':<12} {'axis':<4} {'unit':<6} {'visits':>6} {'backlash':>9} "
          f"{'slope /mo':>10}  {'crossing':<10}  {'next due':<10}{extra}  alerts", file=file)
    for rank, view in enumerate(result.axes, 1):
        j = view.to_dict()
        slope = j["slope_um_per_month"]
        extra = f"  {_forecast(j['last_forecast']):<28}  {_compensation(j['last_compensation']):<18}"
        print(f"{rank:>3} {view.machine_id:<12} {view.axis:<4} {j['unit']:<6} {j['visits']:>6} "
              f"{j['backlash_um']:>9.3f} "
              f"{slope if slope is not None else float('nan'):>10.4f}  "
              f"{j['crossing_date'] or '-':<10}  {j['next_visit_due']:<10}"
              f"{'' if j['days_overdue'] is None else ' overdue ' + str(j['days_overdue']) + ' d'}"
              f"{extra if records else ''}  {', '.join(j['alerts']) or '-'}", file=file)
    print(f"as of {result.parameters['as_of']}", file=file)
    if "index" in result.files:
        print(f"site: {result.files['index']}", file=file)


def _forecast(last) -> str:
    if last is None:
        return "-"
    low, high = last["backlash_low_um"], last["backlash_high_um"]
    band = f" [{low:.2f}, {high:.2f}]" if low is not None else ""
    when = last["for_date"] or (f"{last['for_operating_hours']:g} h"
                                if last["for_operating_hours"] is not None else "?")
    return f"{last['backlash_um']:.2f}{band} {'~' if last['for_date_estimated'] else ''}{when}"


def _compensation(last) -> str:
    if last is None:
        return "-"
    return f"{last['date']} {last['reversal_compensation_um']:.2f}"
