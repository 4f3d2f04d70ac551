"""The ``backlash`` command. Each subcommand lives in ``pipeline.commands.<name>`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; its summary is its job's record. Only the
command named is built (``backlash --help`` imports no command module nor job module). A
command's options come from its job's parameter table, whose constraints are scikit-learn's
(building one command imports scikit-learn); other heavy libraries (torch, mlflow, optuna,
matplotlib) are imported inside ``run``.

Error contract: a user error (``InputError``, or a ``ValueError`` naming a parameter, raised
anywhere below a subcommand, and every bad option) is printed as one line
``backlash COMMAND: error: ...`` with exit code 2, and any output folder the run created is
removed again. A Python parameter named in an error is shown as the option it maps to (the
job's parameter table, the command's ``FLAGS``, else ``--name-with-dashes``). Any other exception is a bug and keeps its
traceback. Notes the library issues (``BacklashWarning``) are printed as ``note: ...`` after a
successful command, never before an error line.

Every command also takes ``--verbose`` (let MLflow, Optuna and alembic print their log lines,
off by default) and ``--tracking-dir DIR`` (where MLflow and Optuna keep their stores:
``pipeline.tracking``).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import os
import re
import sys
import warnings

from features.readings.errors import VERBOSE, BacklashWarning, InputError
from pipeline.commands import command_of, names  # the one command registry
from pipeline.commands.common import check_outputs, remove_created
from pipeline.tracking import TRACKING_DIR

# A value that starts with a minus and is a number, or a comma list of numbers
# (``--reference-scale -1.0036,50.3``: ecmc's gear ratios are negative). argparse's own rule
# takes only a lone number as a value and reads anything else after a minus as an option.
_NUMBER = r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?"
NEGATIVE_VALUE = re.compile(rf"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,{_NUMBER})*$")


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block) and exit code 2, that takes negative
    numbers and comma lists of numbers as values (no option of ours looks like a number)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {_one_line(message)}\n")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of every command. Given the command line ``argv``, only the command it names
    is built in full (the others are a name and a summary, from the job records), so that a
    command, and its ``--help``, imports its own modules only and ``backlash --help`` none."""
    from pipeline.commands.options import checked_types

    commands = names()
    chosen = argv[0] if argv and argv[0] in commands else None
    build = commands if argv is None else (chosen,)  # None: every command, built (tests, docs)
    parser = Parser(
        prog="backlash",
        description="ISO 230-2 positioning tests to backlash predictions, drift alerts, "
        "feature rankings and physical explanations.",
    )
    parser.commands = {}
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in commands:
        summary = _summary(name)
        cmd = sub.add_parser(name, help=summary, description=summary)
        if name not in build:
            continue
        module = command_of(name)
        module.add_arguments(cmd)
        add_common_arguments(cmd)
        checked_types(cmd)
        cmd.set_defaults(_run=module.run)
        parser.commands[name] = cmd
    return parser


def _summary(name: str) -> str:
    """A command's one sentence: its job's record, or the experiment runner's ``HELP``."""
    from pipeline.workflows import NAMES, workflow

    if name in NAMES:
        return workflow(name).summary
    return importlib.import_module(f"pipeline.commands.{name}").HELP


def add_common_arguments(cmd: argparse.ArgumentParser) -> None:
    """The options of every command: the libraries' log lines and where tracking goes."""
    cmd.add_argument("--verbose", action="store_true",
                     help="show the log lines of MLflow, Optuna and alembic (off by default)")
    cmd.add_argument("--tracking-dir", metavar="DIR",
                     help="folder of the MLflow database (mlflow.db), its artifacts "
                          "(mlartifacts/) and the Optuna studies (optuna.db); default "
                          "$BACKLASH_TRACKING_DIR, else the working directory")
    cmd.add_argument("--no-track", action="store_true",
                     help="log nothing to MLflow (a tracked job logs its run by default, from "
                          "the CLI as from Python: pipeline.runner)")


@contextlib.contextmanager
def common_settings(args: argparse.Namespace):
    """``--verbose`` and ``--tracking-dir`` as the environment variables the library reads
    (``BACKLASH_VERBOSE``, ``BACKLASH_TRACKING_DIR``), for this command only; a process it
    forks inherits them."""
    settings = {VERBOSE: "1" if args.verbose else None, TRACKING_DIR: args.tracking_dir}
    before = {name: os.environ.get(name) for name in settings}
    try:
        for name, value in settings.items():
            if value is not None:
                os.environ[name] = value
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(sys.argv[1:] if argv is None else argv)
    try:  # argparse exits on a bad option (one line, code 2) and after --help (code 0)
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # named by the subcommand, like its other option errors
            parser.commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    except SystemExit as stop:
        return int(stop.code or 0)
    created = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", BacklashWarning)
            created = check_outputs(args.command, command_of(args.command), args)
            with common_settings(args):
                code = args._run(args)
    except (InputError, ValueError) as err:
        remove_created(created)
        line = err.line(_flag_namer(args.command)) if isinstance(err, InputError) else str(err)
        print(f"backlash {args.command}: error: {_one_line(line)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        remove_created(created)
        return 130
    except BrokenPipeError:  # `backlash iso --json | head`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    _show(caught)
    return int(code or 0)


def _show(caught: list[warnings.WarningMessage]) -> None:
    """Notes as ``note: ...`` lines (each once, in order); other warnings as Python shows them."""
    seen = set()
    for w in caught:
        if not issubclass(w.category, BacklashWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        elif str(w.message) not in seen:
            seen.add(str(w.message))
            print(f"note: {_one_line(w.message)}", file=sys.stderr)


def _flag_namer(command: str):
    """Python parameter -> the option that sets it (``option_names``), else ``--name``."""
    from pipeline.commands.common import option_names

    flags = option_names(command, command_of(command))
    return lambda name: flags.get(name, f"--{name.replace('_', '-')}")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def program() -> None:
    """The ``backlash`` executable: ``main`` plus what only a whole process may do."""
    from pipeline.tracking import allow_fork

    allow_fork()
    code = main()
    # Every object dies with the process: freezing them spares the interpreter's final garbage
    # collection, which walks all of them (about a second after mlflow and scikit-learn).
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    program()
