"""``backlash uncertainty``: an ISO/TR 230-9 measurement-uncertainty budget from a TOML file."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "uncertainty")
    parser.add_argument("--json", action="store_true",
                        help="print contributors_um, u_P_um and U_um (R_dir, B, R, E, M, A) "
                             "as JSON")


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job

    result = run_job("uncertainty", args)
    if args.json:
        print(result.to_json())
    else:
        print_budget(result, file=sys.stdout)
    return 0


_U_LABELS = {"R_dir": "U(R+), U(R-)", "B": "U(B)", "R": "U(R)", "E": "U(E), U(E+), U(E-)",
             "M": "U(M)", "A": "U(A)"}


def print_budget(result, file) -> None:
    """The budget as a table: each line in every arithmetic, then the expanded uncertainties."""
    b, both = result.budget, result.by_arithmetic()
    names = list(both)
    print(f"uncertainty budget {result.source}: axis {b.axis or '-'}, L = {b.length_mm:g} mm, "
          f"n = {b.cycles}, k = {b.coverage_factor:g}", file=file)
    head = "".join(f"{n:>10}" for n in names)
    print(f"{'line':<18}{head}  {'unit':<11} {'distribution':<12} formula [source]", file=file)
    rows = {n: {ln.key: ln for ln in v.lines} for n, v in both.items()}
    every = max(rows.values(), key=len)  # the paper's lines include the lengths it used
    for key, ln in every.items():
        cells = "".join(f"{rows[n][key].value:>10.4f}" if key in rows[n] else f"{'-':>10}"
                        for n in names)
        print(f"{ln.symbol:<18}{cells}  {ln.unit:<11} {ln.distribution:<12} "
              f"{ln.formula} [{ln.source}]", file=file)
    print(f"expanded uncertainty (k = {b.coverage_factor:g}, n = {b.cycles}; M over 2n)",
          file=file)
    for key, label in _U_LABELS.items():
        cells = "".join(f"{both[n].expanded_um[key]:>10.2f}" for n in names)
        print(f"{label:<18}{cells}  um", file=file)
    print(f"reported: {result.arithmetic}", file=file)
