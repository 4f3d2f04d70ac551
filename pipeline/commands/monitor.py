"""``backlash monitor``: lost motion per machine axis and day from dual-feedback traces."""

from __future__ import annotations

import argparse

from pipeline.results import ALERT_EXIT
from pipeline.workflows.monitor import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
FLAGS = {"traces": "TRACE", "format": "--log-format"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("traces", nargs="+", metavar="TRACE",
                        help="trace table (CSV, Parquet) or Parquet dataset folder partitioned "
                             "by machine_id=, axis=, date= (docs/data-contract.md section 10)")
    parser.add_argument("--out", help="output folder: monitor.json, daily.csv, monitor.html")
    parser.add_argument("--engine", choices=("local", "dask"), default="local",
                        help="where the partitions run (default local: this process)")
    parser.add_argument("--address", metavar="URL",
                        help="Dask scheduler address (tcp://host:8786); default Dask's local "
                             "scheduler")
    parser.add_argument("--threshold-um", type=float, metavar="X",
                        help="lost-motion limit [um]: alert at it, forecast its crossing")
    parser.add_argument("--take-up-mm", type=float, default=0.05, metavar="X",
                        help="travel after a reversal past which the play is taken up "
                             "(default 0.05)")
    parser.add_argument("--store", metavar="STORE",
                        help="fleet store (folder or postgresql:// URL) to record the daily lost motion "
                             "in (docs/fleet.md)")
    parser.add_argument("--json", action="store_true", help="print the axes as JSON")
    raw = parser.add_argument_group("raw controller logs (--log-format camonitor or halsampler)")
    raw.add_argument("--log-format", choices=("trace", "camonitor", "halsampler"),
                     default="trace",
                     help="what TRACE is: trace tables (default) or a raw log per machine axis")
    raw.add_argument("--channels", metavar="MAP",
                     help="commanded=PV,motor=PV,load=PV (halsampler: field numbers or pins)")
    raw.add_argument("--machine", help="the log's machine (default: the commanded PV's IOC)")
    raw.add_argument("--axis", help="the log's axis (default: the commanded PV's axis letter)")
    raw.add_argument("--period-s", type=float, metavar="S",
                     help="halsampler output's sample period [s]")


def run(args: argparse.Namespace) -> int:
    import sys

    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("monitor", args, traces=args.traces, engine=args.engine,
                     address=args.address, threshold_um=args.threshold_um,
                     take_up_mm=args.take_up_mm, store=args.store, format=args.log_format,
                     channels=args.channels, machine=args.machine, axis=args.axis,
                     period_s=args.period_s, out=args.out)
    print_summary(result, file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
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
