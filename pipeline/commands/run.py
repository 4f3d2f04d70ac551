"""``backlash run``: run a declarative experiment file and log it to MLflow."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pipeline.results import ALERT_EXIT

HELP = ("Run an experiment file (TOML steps: a job and its parameters each) and log it to "
        "MLflow.")
# The output folder is checked by the runner (it may come from the file): a failing step
# removes only what that step wrote, never the finished steps' files.
OUTPUTS: dict = {}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="experiment file, e.g. experiments/demo.toml")
    parser.add_argument("--out", help="output folder (default: the file's `out`); relative to "
                                      "the working directory")
    parser.add_argument("--json", action="store_true",
                        help="print the steps and the files they wrote as JSON on stdout")


def run(args: argparse.Namespace) -> int:
    from pipeline import experiment

    loaded = experiment.load(args.file, args.out)
    # the step headers are printed once the run ends: a failing step's error is the first
    # line the run prints (it names the step), not the last after the headers
    headers: list[str] = []
    result = experiment.execute(loaded, progress=lambda done, total, title: headers.append(
        f"[{done + 1}/{total}] {title}") if done < total else None)
    print("\n".join(headers), file=sys.stderr)
    print(file=sys.stderr)
    for done in result.steps:
        alert = " (alert)" if done.code == ALERT_EXIT else ""
        files = _listing([Path(f) for f in done.paths()])
        print(f"[{done.step.index}] {done.step.job}{alert}: {files}", file=sys.stderr)
    if args.json:

        print(result.to_json())
    print(f"experiment {loaded.name!r}: MLflow run {result.run_id} in {result.tracking_uri}; "
          f"outputs in {_short(loaded.out)}/", file=sys.stderr)
    return result.code


def _listing(paths: list) -> str:
    """The step's outputs, a folder standing for the files written inside it."""
    top = [p for p in paths if not any(q in p.parents for q in paths)]
    inside = len(paths) - len(top)
    more = f" (and {inside} files inside)" if inside else ""
    return (", ".join(_short(p) for p in top) + more) if top else "nothing written"


def _short(path) -> str:
    """A path below the working directory as a relative path, for display."""
    relative = os.path.relpath(path)
    return str(path) if relative.startswith("..") else relative
