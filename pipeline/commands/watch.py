"""``backlash watch``: the watcher's events as they happen, one line each: JSON on stdout with
``--json`` (a service's status feed, its last line the result), else a short line on
stderr."""

from __future__ import annotations

import argparse

from pipeline.commands.parameters import add_parameters


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_parameters(parser, "watch")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON status line per event on stdout, the result last")


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    from pipeline.commands.data import run_job

    def status(line: dict) -> None:
        if args.json:
            print(json.dumps(line, allow_nan=False, default=str), flush=True)
        else:
            shown = " ".join(f"{k}={v}" for k, v in line.items() if k not in ("time", "event"))
            print(f"{line.get('time', '')} {line.get('event')} {shown}", file=sys.stderr,
                  flush=True)

    result = run_job("watch", args, status=status)
    if args.json:  # the last line: the result, as bl.watch returns it
        print(json.dumps(result.to_dict(), allow_nan=False, default=str), flush=True)
    else:
        print(repr(result), file=sys.stderr)
    return 0
