"""The command of a job that has no command module of its own: its options from its parameter
table, ``--json``, and the result's short form on stderr. A new job needs a command module
only to print more than that (a table, a plot)."""

from __future__ import annotations

import argparse
from types import SimpleNamespace

from pipeline.commands.parameters import add_parameters
from pipeline.steps.parameters import JSON_HELP


def command(job: str) -> SimpleNamespace:
    """``add_arguments(parser)`` and ``run(args)`` of job ``job``."""

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        add_parameters(parser, job)
        parser.add_argument("--json", action="store_true", help=JSON_HELP)

    def run(args: argparse.Namespace) -> int:
        import sys

        from pipeline.commands.data import run_job
        from pipeline.results import ALERT_EXIT

        result = run_job(job, args)
        print(repr(result), file=sys.stderr)
        if args.json:
            print(result.to_json())
        return ALERT_EXIT if getattr(result, "alerts", None) else 0

    return SimpleNamespace(add_arguments=add_arguments, run=run)
