"""The ``backlash`` command. Each subcommand lives in ``pipeline.commands.<name>`` and exposes
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Command modules import only light
modules at top level; heavy libraries (torch, mlflow, sklearn) are imported inside ``run``.

Error contract: a user error (``InputError``, or a ``ValueError`` naming a parameter, raised
anywhere below a subcommand, and every bad option) is printed as one line
``backlash COMMAND: error: ...`` with exit code 2, and any output folder the run created is
removed again. Any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import sys
from pathlib import Path

from features.readings.errors import InputError

# Order is the order shown in --help.
COMMANDS = ("convert", "iso", "simulate", "train", "predict", "compare", "tune", "rank", "drift", "discover", "hidden-effects", "compensate", "run")

# Outputs each command writes, by argparse dest: a folder, or a file.
FOLDER, FILE = "folder", "file"
OUTPUTS = {
    "convert": {"out": FILE}, "iso": {"plot": FILE}, "predict": {"out": FILE},
    "simulate": {"out": FOLDER}, "train": {"out": FOLDER}, "compare": {"out": FOLDER},
    "rank": {"out": FOLDER}, "drift": {"out": FOLDER}, "discover": {"out": FOLDER},
    "hidden-effects": {"out": FOLDER}, "run": {"out": FOLDER}, "compensate": {"out": FOLDER},
    "replicate": {"out": FOLDER},
}


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block) and exit code 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {_one_line(message)}\n")


def build_parser() -> argparse.ArgumentParser:
    from pipeline.commands.common import checked_types

    parser = Parser(
        prog="backlash",
        description="ISO 230-2 positioning tests to backlash predictions, drift alerts, "
        "feature rankings and physical explanations.",
    )
    parser.commands = {}
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = importlib.import_module(f"pipeline.commands.{name.replace('-', '_')}")
        cmd = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        checked_types(cmd)
        cmd.set_defaults(_run=module.run)
        parser.commands[name] = cmd
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # named by the subcommand, like its other option errors
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    created = []
    try:
        created = _check_outputs(args)
        code = args._run(args)
    except (InputError, ValueError) as err:
        _remove_created(created)
        line = err.line() if isinstance(err, InputError) else str(err)
        print(f"backlash {args.command}: error: {_one_line(line)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _remove_created(created)
        return 130
    except BrokenPipeError:  # `backlash iso --json | head`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    return int(code or 0)


def _check_outputs(args) -> list[Path]:
    """Refuse output paths that cannot work before any work is done; return the folders
    this run will create (removed again if the run ends in a user error)."""
    from features.readings.fileio import check_output

    created = []
    for dest, kind in OUTPUTS.get(args.command, {}).items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        root = check_output(value, kind, f"--{dest.replace('_', '-')}")
        if root is not None:
            created.append(root)
    return created


def _remove_created(folders: list[Path]) -> None:
    for folder in folders:
        shutil.rmtree(folder, ignore_errors=True)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


if __name__ == "__main__":
    sys.exit(main())
