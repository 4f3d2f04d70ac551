"""``backlash compensate``: controller compensation files from ISO tests or a trained predictor."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_readings_argument
from pipeline.compensation import CONTROLLERS, SIGNS
from pipeline.workflows.compensate import WORKFLOW

HELP = WORKFLOW.summary
OUTPUTS = {"out": "folder"}  # output paths by argparse dest: checked before any work
FLAGS = {"data": "DATA|MODEL_DIR"}


def controller_help() -> str:
    """The ``--controller`` help, from the controller records."""
    aliases = [f"{a}={c.name}" for c in CONTROLLERS.values() for a in c.aliases]
    return (f"one or more of {', '.join(CONTROLLERS)} (comma-separated), or all; "
            f"aliases {', '.join(aliases)}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_readings_argument(parser, "source", metavar="DATA|MODEL_DIR", skip=("axis",),
                          help="model directory (backlash train) or readings file (ISO tests)")
    parser.add_argument("--controller", required=True, help=controller_help())
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--conditions", metavar="NAME=VALUE,...",
                        help="conditions for a predictor, e.g. feed_mm_min=500,machine_temp_c=21")
    parser.add_argument("--axis", help="axis name: a predictor's axis (default X), or only this "
                                       "axis's tests of DATA or a wear map's axes")
    parser.add_argument("--at-hours", type=float, metavar="H",
                        help="wear map: forecast the table for this reading of the axis's "
                             "operating-hours counter (default: the middle of the next "
                             "maintenance interval)")
    parser.add_argument("--at-date", metavar="YYYY-MM-DD",
                        help="wear map: forecast the table for this day, through the axis's "
                             "usage rate when the model records it")
    parser.add_argument("--spacing", type=float, metavar="MM",
                        help="table spacing of equidistant formats (default: a quarter of the "
                             "smallest target interval, rounded down to 1/2/2.5/5 x 10^k)")
    parser.add_argument("--reference-mm", type=float,
                        help="reference point where SINUMERIK/Fanuc/Heidenhain tables are 0 "
                             "(default: the table point nearest 0)")
    parser.add_argument("--fanuc-unit-um", type=float, default=1.0,
                        help="Fanuc detection unit [um] (default 1)")
    parser.add_argument("--active", action="append", metavar="FILE",
                        help="DATA was measured with this compensation file active (one "
                             "controller's file for one machine axis; repeat for its table and "
                             "its parameter file): write the active file plus the measured "
                             "residual, and the change per target")
    parser.add_argument("--sign", choices=SIGNS,
                        help="what a positive table value means at this site (SINUMERIK, Fanuc, "
                             "Heidenhain tables; default: each controller's documented "
                             "convention); also how --active is read")
    parser.add_argument("--store", metavar="STORE",
                        help="fleet store (folder or postgresql:// URL, made by backlash ingest) "
                             "to record this compensation in; backlash fleet shows the last one")
    parser.add_argument("--uncertainty", metavar="BUDGET.toml",
                        help="uncertainty budget of the measurement (as backlash iso takes): "
                             "say whether each file set's residual is within or beyond U(B)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    parser.add_argument("--verify", action="store_true",
                        help="twin data only: re-run the ISO tests with the written files "
                             "applied; report before/after (verify.html); exit 3 if worse")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.data import run_job

    result = run_job("compensate", args, "compensate", data=args.source,
                     controller=args.controller, format=args.format,
                     conditions=args.conditions, at_hours=args.at_hours, at_date=args.at_date,
                     axis=args.axis, spacing=args.spacing, reference_mm=args.reference_mm,
                     fanuc_unit_um=args.fanuc_unit_um, active=args.active, sign=args.sign,
                     verify=args.verify, uncertainty=args.uncertainty, out=args.out,
                     store=args.store)
    print("\n".join(result.summary()), file=sys.stderr)
    if result.recorded is not None:
        print(result.recorded.text, file=sys.stderr)
    if args.json:
        print(dumps(result.to_json()))
    return 0 if result.passed else 3
