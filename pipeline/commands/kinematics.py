"""``backlash kinematics``: the rotary axes' geometric errors and plays from probed spheres.

Without ``--json`` it prints per machine and visit a table: each of the 12 errors with its
standard uncertainty (a dash where the probing cannot separate it), the inseparable groups
with the sum the probing does give, each rotary axis's play with its uncertainty, and the
residual of the fit.
"""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "kinematics")
    parser.add_argument("--json", action="store_true",
                        help="print every machine's errors, plays, inseparable groups and "
                             "residual as JSON (data contract section 13)")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.common import show
    from pipeline.commands.data import run_job

    return show(run_job("kinematics", args), args, table)


def _num(value, width: int = 10) -> str:
    return f"{'–' if value is None else format(value, '.3f'):>{width}}"


def _unit(name: str) -> str:
    """An error's unit, the last part of its name (``delta_x_A_um``: um)."""
    return name.rsplit("_", 1)[1]


def table(found: dict) -> str:
    """The printed table of a kinematics result's JSON (``KinematicsResult.to_dict``)."""
    lines = []
    for m in found["machines"]:
        lines.append(f"{m['machine_id']} visit {m['visit']} ({m['kinematics']}), tests "
                     f"{m['test_id']}: {m['points']} sphere centres, residual "
                     f"{m['residual_rms_um']:.3f} um rms, rank {m['rank']} of "
                     f"{len(m['errors']) + len(m['play_arcsec'])}")
        lines.append(f"  {'error':<20}{'value':>10}{'u':>10}  unit")
        grouped = {n for g in m["not_identifiable"] for n in g}
        for name, value in m["errors"].items():
            why = "  inseparable (see below)" if name in grouped else ""
            lines.append(f"  {name:<20}{_num(value)}{_num(m['errors_u'][name])}  "
                         f"{_unit(name):<6}{why}".rstrip())
        for combo in m["identifiable_combinations"]:
            lines.append(f"  inseparable: {' and '.join(combo['names'])}; only "
                         f"{combo['label']} = {combo['value']:.3f} ± {combo['u']:.3f} "
                         f"{_unit(combo['names'][0])}")
        for axis, play in m["play_arcsec"].items():
            lines.append(f"  {'play ' + axis:<20}{_num(play)}"
                         f"{_num(m['play_u_arcsec'][axis])}  arcsec")
    return "\n".join(lines)
