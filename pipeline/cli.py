"""The ``backlash`` command. Each subcommand lives in ``pipeline.commands.<name>`` and exposes
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Command modules import only light
modules at top level; heavy libraries (torch, mlflow, sklearn) are imported inside ``run``."""

from __future__ import annotations

import argparse
import importlib
import sys

from features.readings.errors import InputError

# Order is the order shown in --help.
COMMANDS = ("convert", "iso", "simulate", "train", "predict", "compare", "tune", "rank", "replicate", "drift", "discover", "hidden-effects", "run")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="backlash",
        description="ISO 230-2 positioning tests to backlash predictions, drift alerts, "
        "feature rankings and physical explanations.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = importlib.import_module(f"pipeline.commands.{name.replace('-', '_')}")
        cmd = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        code = args._run(args)
    except InputError as err:
        print(f"backlash {args.command}: error: {err.line()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
