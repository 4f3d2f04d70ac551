"""``backlash stiffness``: static stiffness from loaded double-ballbar (LDBB) circles.

Without ``--json`` it prints per machine the stiffness of every centre along its plane's axes
with its standard uncertainty, and the form of the stiffness map over the workspace.
"""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "stiffness")
    parser.add_argument("--json", action="store_true",
                        help="print every centre's stiffness and compliance, the map and "
                             "(with --at) the deflections as JSON (data contract section 12)")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.common import show
    from pipeline.commands.data import run_job

    return show(run_job("stiffness", args), args, table)


def _num(value, fmt: str = ".2f", width: int = 9) -> str:
    return f"{'–' if value is None else format(value, fmt):>{width}}"


def table(found: dict) -> str:
    """The printed table of a stiffness result's JSON (``StiffnessResult.to_dict``)."""
    lines = []
    for m in found["machines"]:
        lines.append(f"{m['machine_id']}: {len(m['centres'])} centres; stiffness [N/um] ± "
                     "standard uncertainty along each axis of the circle's plane")
        lines.append(f"  {'visit':<8}{'plane':<6}{'centre x, y, z [mm]':>28}"
                     f"{'loads [N]':>18}  stiffness")
        for c in m["centres"]:
            where = ", ".join(f"{v:g}" for v in c["centre_mm"])
            loads = " ".join(f"{v:g}" for v in c["loads_n"])
            k, u = c["stiffness_n_per_um"], c["stiffness_u_n_per_um"]
            axes = "  ".join(f"{a} {_num(k[a], width=7)} ± {_num(u[a], width=5)}" for a in k)
            lines.append(f"  {c['visit']:<8}{c['plane']:<6}{where:>28}{loads:>18}  {axes}")
        found_map = m["map"]
        decided = "" if found_map["decided"] else " (not decided: see the notes)"
        lines.append(f"  map: {found_map['form']}{decided}; {found_map['reason']}")
    if found.get("deflection"):
        lines.append(f"deflection at {len(found['deflection'])} points: --out writes "
                     "deflection.csv, --json prints it")
    return "\n".join(lines)
