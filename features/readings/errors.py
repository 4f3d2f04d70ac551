"""The one error type a user can cause, printed as a single line with exit code 2."""

from __future__ import annotations


class InputError(Exception):
    """Bad user input: names the file, the row and column where known, and what was expected.

    Rows are 1-based data rows as a spreadsheet shows them (the header is row 1,
    so the first data row is row 2).
    """

    def __init__(self, message: str, *, file: str | None = None, row: int | None = None,
                 column: str | None = None):
        self.message = message
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        super().__init__(self.line())

    def line(self) -> str:
        where = [self.file] if self.file else []
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.column is not None:
            where.append(f"column {self.column!r}")
        return (": ".join([", ".join(where), self.message]) if where else self.message)
