"""What the library tells a user: the one user-error type, notes and progress.

The library never prints. A user error is an ``InputError`` (one line: file, row, column or
parameter, what was expected); something a user should know is a note, issued as a
``BacklashWarning`` (the CLI prints it as ``note: ...`` after the command's output, never before
an error line); long work reports progress to a callback (the CLI draws a progress bar).
"""

from __future__ import annotations

import functools
import logging
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

# progress(done, total, what): called as work advances; ``total`` may be 0 when unknown.
Progress = Callable[[int, int, str], None]
# The product's packages: a note names the first line outside them (``caller_level``).
PACKAGES = tuple(str(Path(__file__).resolve().parents[2] / name)
                 for name in ("features", "models", "pipeline", "backlash"))
VERBOSE = "BACKLASH_VERBOSE"  # set: the libraries' log lines reach the terminal


class InputError(ValueError):
    """Bad user input: names the file, the row and column, or the Python parameter where known,
    and what was expected.

    Rows are 1-based data rows as a spreadsheet shows them (the header is row 1,
    so the first data row is row 2). ``parameter`` is the Python parameter a library caller
    passed; the CLI shows it as the option it maps to.
    """

    def __init__(self, message: str, *, file: str | None = None, row: int | None = None,
                 column: str | None = None, parameter: str | None = None):
        self.message = message
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        self.parameter = parameter
        super().__init__(self.line())

    def line(self, name_of: Callable[[str], str] | None = None) -> str:
        """The error as one line; ``name_of`` renames the parameter (the CLI's option)."""
        where = [self.file] if self.file else []
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.column is not None:
            where.append(f"column {self.column!r}")
        if self.parameter is not None:
            where.append(name_of(self.parameter) if name_of else f"parameter {self.parameter!r}")
        return (": ".join([", ".join(where), self.message]) if where else self.message)


class BacklashWarning(UserWarning):
    """A note for the user: data left out, a choice made for them, a limit of the evidence."""


def note(message: str) -> None:
    """Issue ``message`` as a ``BacklashWarning`` at the line that called the product
    (``caller_level``), so Python names the user's line, not the library's (shown once per
    place by Python's default filter; the CLI shows every one)."""
    warnings.warn(message, BacklashWarning, stacklevel=caller_level())


def caller_level() -> int:
    """The ``stacklevel`` for ``warnings.warn`` called by the function that calls this one:
    walking up the stack, the first frame outside ``PACKAGES`` (the product's code) above the
    outermost frame inside them, so that a library between two of the product's frames
    (pandas calling back into a workflow) is not taken for the caller; the outermost frame
    when there is none above (the CLI)."""
    frame = sys._getframe(2)  # the caller of the function that wants the level
    level, outermost = 2, 1  # warnings.warn(stacklevel=2) in that function names this frame
    while frame is not None:
        if _inside(frame.f_code.co_filename):
            outermost = level
        frame, level = frame.f_back, level + 1
    return min(outermost + 1, level - 1)


@functools.lru_cache(maxsize=1024)
def _inside(filename: str) -> bool:
    path = os.path.realpath(filename)
    return any(path.startswith(root + os.sep) for root in PACKAGES)


def verbose() -> bool:
    """Whether the user asked to see the log lines of the libraries the product runs (MLflow,
    alembic, Optuna): ``BACKLASH_VERBOSE`` set to anything but ``0`` (the CLI's
    ``--verbose``), or a logging configuration of their own (a handler on the root logger,
    e.g. ``logging.basicConfig``). Otherwise those lines are off (``pipeline.tracking``,
    ``models.estimators.tuning``)."""
    return (os.environ.get(VERBOSE, "") not in ("", "0")
            or bool(logging.getLogger().handlers))


def report(progress: Progress | None, done: int, total: int, what: str = "") -> None:
    """Call ``progress`` if the caller gave one."""
    if progress is not None:
        progress(done, total, what)
