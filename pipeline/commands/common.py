"""What the commands share: comma lists, output checks and the progress bar (the checked option
types are in ``options``, the DATA argument of every command that reads readings in ``data``)."""

from __future__ import annotations

import contextlib
import shutil
import sys
from pathlib import Path

from features.readings import schema
from features.readings.errors import InputError

FORMATS = schema.FORMATS  # the input layouts every --format option offers


def parse_list(text: str | None, parameter: str) -> list[str] | None:
    """A comma-separated option as a list of names (None when not given)."""
    from pipeline.workflows import each_once

    if text is None:
        return None
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names:
        raise InputError("is empty; give comma-separated names", parameter=parameter)
    return each_once(names, parameter)


def parse_features(text: str | None) -> list[str] | None:
    return parse_list(text, "features")


def read_truth(path):
    from models.evaluation import read_truth

    return read_truth(path)


def check_outputs(command: str, args) -> list[Path]:
    """Refuse output paths that cannot work before any work is done; return the folders
    this run will create (removed again if the run ends in a user error)."""
    import importlib

    from features.readings.fileio import check_output

    module = importlib.import_module(f"pipeline.commands.{command.replace('-', '_')}")
    created = []
    for dest, kind in getattr(module, "OUTPUTS", {}).items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        root = check_output(value, kind, f"--{dest.replace('_', '-')}")
        if root is not None:
            created.append(root)
    return created


@contextlib.contextmanager
def progress_bar(what: str = ""):
    """A ``progress(done, total, what)`` callback drawing a tqdm bar on stderr (only when
    stderr is a terminal: logs and pipes stay clean)."""
    from tqdm import tqdm

    bar = tqdm(desc=what, disable=not sys.stderr.isatty(), leave=False, file=sys.stderr)

    def progress(done: int, total: int, step: str = "") -> None:
        if total and bar.total != total:
            bar.total = total
        if step:
            bar.set_postfix_str(step, refresh=False)
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        bar.close()


def remove_created(folders: list[Path]) -> None:
    for folder in folders:
        shutil.rmtree(folder, ignore_errors=True)


def add_limit_arguments(parser) -> None:
    """The limits ``drift`` and ``fleet`` compare each axis with, in its own unit:
    ``--threshold-um`` (linear axes), ``--threshold-arcsec`` (rotary axes), ``--limits``."""
    parser.add_argument("--threshold-um", type=float, metavar="X",
                        help="backlash limit of the linear axes [um]: forecast the date each "
                             "crosses it")
    parser.add_argument("--threshold-arcsec", type=float, metavar="X",
                        help="backlash limit of the rotary axes (A, B, C) [arcsec]")
    parser.add_argument("--limits", metavar="LIMITS.toml",
                        help="limits per machine and axis, each in its unit ([M01] X_um = 8.0, "
                             "C_arcsec = 40.0); other axes take --threshold-um/-arcsec")


def add_as_of_argument(parser) -> None:
    """``--as-of DATE``: the day ``drift`` and ``fleet`` are computed as of (default today)."""
    parser.add_argument("--as-of", metavar="YYYY-MM-DD",
                        help="compute the view as of this day (default today, UTC): tests "
                             "started later are left out; overdue visits and limits passed "
                             "since the last visit alert")


def add_trend_arguments(parser) -> None:
    """The options of the trend analysis per machine axis (``models.drift``), the same for
    ``drift`` and ``fleet``: ``--warn-months``, ``--alpha``, ``--min-jump-sigma``."""
    parser.add_argument("--warn-months", type=float, default=6.0,
                        help="alert when the crossing may come within this many months of "
                             "the last visit (default 6)")
    parser.add_argument("--alpha", type=float, default=0.05,
                        help="significance level of trend tests and intervals (default 0.05)")
    parser.add_argument("--min-jump-sigma", type=float, default=3.0,
                        help="a change point must move the level by this many standard "
                             "errors (default 3)")
