"""``backlash compensate``: controller compensation files from ISO tests or a trained predictor."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.data import add_readings_argument
from pipeline.compensation import CONTROLLERS
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
                                       "axis's tests of DATA")
    parser.add_argument("--spacing", type=float, metavar="MM",
                        help="table spacing of equidistant formats (default: a quarter of the "
                             "smallest target interval, rounded down to 1/2/2.5/5 x 10^k)")
    parser.add_argument("--reference-mm", type=float,
                        help="reference point where SINUMERIK/Fanuc/Heidenhain tables are 0 "
                             "(default: the table point nearest 0)")
    parser.add_argument("--fanuc-unit-um", type=float, default=1.0,
                        help="Fanuc detection unit [um] (default 1)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    parser.add_argument("--verify", action="store_true",
                        help="twin data only: re-run the ISO tests with the written files "
                             "applied; report before/after (verify.html); exit 3 if worse")


def run(args: argparse.Namespace) -> int:
    from features.readings.fileio import dumps
    from pipeline.commands.common import progress_bar

    source = _source(args)
    with progress_bar("compensate") as progress:
        result = WORKFLOW.function(
            source, controller=args.controller, format=args.format,
            conditions=args.conditions, axis=args.axis or "X", spacing=args.spacing,
            reference_mm=args.reference_mm, fanuc_unit_um=args.fanuc_unit_um,
            verify=args.verify, progress=progress)
    result.write(args.out)
    _print_summary(result)
    if args.json:
        print(dumps(result.to_json()))
    return 0 if result.passed else 3


def _source(args):
    """A model directory as given (only --axis applies to it), else the selected readings."""
    import os

    from features.readings.errors import InputError
    from pipeline.commands.data import readings_arg, selected
    from pipeline.store import is_store

    if not os.path.isdir(args.source) or is_store(args.source):
        return readings_arg(args, "source")
    given = selected(args, skip=("axis",))
    if given:
        raise InputError(f"--{next(iter(given))} selects tests of readings; {args.source} is a "
                         "model directory")
    return args.source


def _print_summary(result) -> None:
    for p in result.profiles:
        print(f"{p.machine_id} {p.axis} ({p.source}): backlash {p.backlash:.3f} um, "
              f"{len(p.target)} targets", file=sys.stderr)
        for note in p.notes:
            print(f"  note: {note}", file=sys.stderr)
    for w in result.written:
        files = ", ".join(w["files"].values())
        interp = w["interpolation_error_um"]
        extra = "" if interp is None else f"; interpolation error at targets {interp:.4f} um"
        unconfirmed = (f"; not confirmed: {'; '.join(w['unconfirmed'])}"
                       if w["unconfirmed"] else "")
        print(f"{w['controller']} {w['machine_id']} {w['axis']}: {files}{extra}{unconfirmed}",
              file=sys.stderr)
    for c in result.checks():
        print(f"verify {c['controller']} {c['machine_id']} {c['axis']}: "
              f"{'passed' if c['passed'] else 'FAILED'}; B {c['before']['B']:.3f} -> "
              f"{c['after']['B']:.3f} um, E {c['before']['E']:.3f} -> {c['after']['E']:.3f} um "
              f"-> {c['report']}", file=sys.stderr)
