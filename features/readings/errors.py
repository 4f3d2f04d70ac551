"""What the library tells a user: the one user-error type, notes and progress.

The library never prints. A user error is an ``InputError`` (one line: file, row, column or
parameter, what was expected); something a user should know is a note, issued as a
``BacklashWarning`` (the CLI prints it as ``note: ...`` after the command's output, never before
an error line); long work reports progress to a callback (the CLI draws a progress bar).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

# progress(done, total, what): called as work advances; ``total`` may be 0 when unknown.
Progress = Callable[[int, int, str], None]


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


def note(message: str, stacklevel: int = 2) -> None:
    """Issue ``message`` as a ``BacklashWarning`` (shown once per place by Python's default
    filter; the CLI shows every one)."""
    warnings.warn(message, BacklashWarning, stacklevel=stacklevel + 1)


def report(progress: Progress | None, done: int, total: int, what: str = "") -> None:
    """Call ``progress`` if the caller gave one."""
    if progress is not None:
        progress(done, total, what)
