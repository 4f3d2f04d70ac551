"""``backlash ingest``: validate readings files and add their tests to a fleet store."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "ingest")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def run(args: argparse.Namespace) -> int:
    import sys

    from pipeline.commands.data import run_job
    from pipeline.workflows.ingest import IngestInterrupted

    try:
        result = run_job("ingest", args, "ingest")
    except IngestInterrupted as stop:  # say what the store kept, then stop as Ctrl-C does
        print(f"backlash ingest: interrupted: {stop.text}", file=sys.stderr)
        raise
    for f in result.inputs:
        replaced = f"{f['replaced']} replaced, " if f["replaced"] else ""
        print(f"{f['file']}: {f['tests']} tests, {f['readings']} readings: {f['added']} added, "
              f"{replaced}{f['unchanged']} already stored", file=sys.stderr)
    print(f"store {result.store}: {result.tests_in_store} tests", file=sys.stderr)
    if args.json:
        print(result.to_json())
    return 0
