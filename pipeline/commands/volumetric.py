"""``backlash volumetric``: the seed paper's volumetric compensation replicated on the twin."""

from __future__ import annotations

import argparse
import sys

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "volumetric")
    parser.add_argument("--json", action="store_true",
                        help="print diagonals (before_um, traditional_um, abbe_um), axes, the "
                             "finding and the identification errors as JSON")


def run(args: argparse.Namespace) -> int:
    from pipeline.commands.data import run_job
    from pipeline.workflows.volumetric import PAPER_TABLE1

    result = run_job("volumetric", args)
    if args.json:
        print(result.to_json())
        return 0
    print(f"volumetric compensation on the twin (seed {result.seed}): extreme deviation [um]; "
          "paper's Table 1 in brackets")
    print(f"{'':<6}{'before':>16}{'traditional':>18}{'Abbe-aware':>18}  Abbe below")
    for what, rows in (("diagonals", result.diagonals), ("axes", result.axes)):
        paper = PAPER_TABLE1[what]
        for name, v in rows.items():
            p = paper[name]
            below = abs(v["abbe_um"]) < abs(v["traditional_um"])
            print(f"{name:<6}{v['before_um']:>8.1f} ({p['before_um']:>5.1f})"
                  f"{v['traditional_um']:>10.1f} ({p['traditional_um']:>5.1f})"
                  f"{v['abbe_um']:>10.1f} ({p['abbe_um']:>5.1f})  {'yes' if below else 'no'}")
    holds = all(result.finding.values())
    print(f"Abbe-aware below traditional on every diagonal: {'yes' if holds else 'no'}")
    if args.out:
        print(f"-> {args.out}/volumetric.json, diagonals.csv, circles.csv", file=sys.stderr)
    return 0
