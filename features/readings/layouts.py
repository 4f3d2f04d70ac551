"""The input layouts a readings file may have: one record per layout.

A record names the layout (the ``--format`` choice), says how a file of it is recognised and
where its reader lives, and carries the words the help texts and the docs' table show. The
CLI's ``--format`` choices (``schema.FORMATS``), the help text of every readings argument
(``schema.DATA_HELP``) and the "unknown format" error are generated from ``LAYOUTS``, so a
new layout is one record here plus its reader (see ``docs/extending.md``).

This module is light (no pandas): ``backlash --help`` reads it. Readers are imported on
first use from their ``reader`` path.

Recognition (``detect_format``) runs in two passes over ``LAYOUTS``: first each layout's
``signature`` (a file suffix or marker text decisive on its own), then each ``header`` (the
column names of a CSV's first line). The first match wins.
"""

from __future__ import annotations

import codecs
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from features.readings.errors import InputError

# Bytes of a file's start that the signatures look at.
HEAD_BYTES = 65536
# Characters of a text file's start that the signatures and headers look at.
HEAD_CHARS = 8192
# Spellings of the paper's first deviation column (Table 2): they mark the paper layout.
PAPER_DEV_LIN_F = ("dev_lin_f_mm", "dev_lin_f [mm]", "dev_lin_f")


class Probe:
    """What recognition looks at, read once and only when asked: the raw start of the file,
    its text (None when it is not text) and the column names of its first line."""

    def __init__(self, path: Path, text: str | None = None):
        self.path = Path(path)
        self.suffix = self.path.suffix.lower()
        self._text = text
        self.error: InputError | None = None

    @cached_property
    def raw(self) -> bytes:
        try:
            with open(self.path, "rb") as fh:
                return fh.read(HEAD_BYTES)
        except OSError:
            return b""

    @cached_property
    def text(self) -> str | None:
        """The start of the file as text; None (the reason kept in ``error``) otherwise."""
        if self._text is None:
            try:
                self._text = read_text(self.path)
            except InputError as err:
                self.error = err
                return None
        return self._text[:HEAD_CHARS]

    @cached_property
    def header(self) -> str:
        """The first line, lower case ("" for an empty or non-text file)."""
        return self.text.splitlines()[0].lower() if self.text and self.text.strip() else ""

    @cached_property
    def names(self) -> set[str]:
        """Column names of the first line, read as CSV."""
        return {c.strip().strip('"') for c in self.header.split(",")} if self.header else set()


@dataclass(frozen=True)
class Layout:
    """One input layout.

    Attributes
    ----------
    name : str
        The layout's name: a ``--format`` choice and the ``format`` parameter of ``read``.
    help : str
        Its words in the help text of every readings argument ("paper Table-2 CSV").
    expected : str
        What a file of this layout holds, for the "unknown format" error and the docs.
    suffixes : tuple of str
        File name suffixes such files usually have (documentation; recognition is by
        ``signature`` and ``header``).
    reader : str
        ``"module:function"``; ``function(path) -> DataFrame`` returns long readings, not yet
        validated, with a ``validation.ROW`` column of file rows when they are known.
    signature : callable, optional
        ``signature(probe) -> bool``: the file is of this layout whatever its content says.
    header : callable, optional
        ``header(names) -> bool`` on the set of column names of a CSV's first line.
    options : tuple of str
        Keyword options its reader takes beyond the path (a raw log's channel mapping); no
        other layout accepts them.
    """

    name: str
    help: str
    expected: str
    suffixes: tuple[str, ...]
    reader: str
    signature: Callable[[Probe], bool] | None = None
    header: Callable[[set[str]], bool] | None = None
    options: tuple[str, ...] = ()

    def read(self, path, **options):
        """The file's long readings (not validated): the reader, imported on first use, given
        ``options`` (only those of ``self.options`` whose value is not None)."""
        given = {name: value for name, value in options.items() if value is not None}
        extra = [name for name in given if name not in self.options]
        if extra:
            takers = _or_list([r.name for r in LAYOUTS if extra[0] in r.options])
            raise InputError(f"applies to {takers} files only; this file is {self.name!r}",
                             file=path, parameter=extra[0])
        module, _, function = self.reader.partition(":")
        return getattr(importlib.import_module(module), function)(Path(path), **given)


def _rtl_signature(probe: Probe) -> bool:
    # Before any text decoding: .rtl files may be Latin-1.
    return probe.suffix == ".rtl" or (b"TARGET DATA::" in probe.raw and b"RUNS::" in probe.raw)


def _ecmc_signature(probe: Probe) -> bool:
    return probe.text is not None and ("TGT_DATA[" in probe.text or "REF_DATA_" in probe.text)


def _camonitor_signature(probe: Probe) -> bool:
    if probe.text is None:
        return False
    from features.readings.camonitor import looks_like_camonitor  # numeric: on use only

    return looks_like_camonitor(probe.text)


LAYOUTS: tuple[Layout, ...] = (
    Layout(
        name="canonical", help="canonical CSV or Parquet",
        expected="a readings table (columns machine_id, axis, test_id, method, target, "
                 "direction, cycle, deviation_um)",
        suffixes=(".csv", ".parquet"), reader="features.readings.formats:read_canonical",
        signature=lambda probe: probe.suffix == ".parquet",
        header=lambda names: {"direction", "method"} <= names),
    Layout(
        name="paper", help="paper Table-2 CSV",
        expected="a paper Table-2 file (Dev_lin_f ...)",
        suffixes=(".csv",), reader="features.readings.formats:read_paper",
        header=lambda names: any(alias in names for alias in PAPER_DEV_LIN_F)),
    Layout(
        name="ecmc", help="ecmc .dat",
        expected="an ecmc *_ISO230.dat file (TGT_DATA/REF_DATA lines)",
        suffixes=(".dat",), reader="features.readings.formats:read_ecmc",
        signature=_ecmc_signature),
    Layout(
        name="rtl", help="Renishaw .rtl",
        expected="a Renishaw .rtl file (TARGET DATA::, RUNS::, DEVIATIONS:: sections)",
        suffixes=(".rtl",), reader="features.readings.rtl:read_rtl",
        signature=_rtl_signature),
    Layout(
        name="camonitor", help="EPICS camonitor log",
        expected="an EPICS camonitor log of an ISO 230-2 run (lines 'PV date time value')",
        suffixes=(".log", ".txt"),
        reader="features.readings.approaches:read_camonitor_readings",
        signature=_camonitor_signature, options=("channels", "reference_scale", "unit")),
)


def _or_list(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


def _derive() -> None:
    """The views read from ``LAYOUTS``, computed again whenever a record comes or goes (read
    them as ``layouts.FORMATS``, not copied at import, to see a registered layout)."""
    global BY_NAME, FORMATS, DATA_HELP, UNKNOWN_FORMAT
    BY_NAME = {record.name: record for record in LAYOUTS}
    # The ``--format`` choices: detection first, then every layout.
    FORMATS = ("auto", *BY_NAME)
    # Help text of every readings (DATA) argument.
    DATA_HELP = "readings file: " + _or_list([record.help for record in LAYOUTS])
    # The "unknown format" error: what an accepted file holds.
    UNKNOWN_FORMAT = "unknown format: expected " + _or_list([r.expected for r in LAYOUTS])


_derive()


def register(record: Layout, before: str | None = None) -> Layout:
    """Add a layout from outside this module (recognised after the layouts above, or just
    before layout ``before`` when its signature or header must win over that one's).

    Raises
    ------
    ValueError
        When a layout of that name exists already.
    """
    global LAYOUTS
    if record.name in BY_NAME or record.name == "auto":
        raise ValueError(f"layout {record.name!r} exists already")
    at = [r.name for r in LAYOUTS].index(before) if before else len(LAYOUTS)
    LAYOUTS = (*LAYOUTS[:at], record, *LAYOUTS[at:])
    _derive()
    return record


def unregister(name: str) -> None:
    """Remove layout ``name`` (one added by ``register``)."""
    global LAYOUTS
    layout(name)
    LAYOUTS = tuple(r for r in LAYOUTS if r.name != name)
    _derive()


def layouts_table() -> str:
    """The docs' table of layouts (``docs/input-formats.md``, filled in by ``docs/hooks.py`` as
    the site is built)."""
    def cell(text: str) -> str:
        return text.replace("*", r"\*").replace("|", r"\|")

    rows = ["| format | suffixes | help text | a file of it holds | reader |",
            "|---|---|---|---|---|"]
    rows += [f"| `{r.name}` | {', '.join(f'`{s}`' for s in r.suffixes)} | {cell(r.help)} | "
             f"{cell(r.expected)} | `{r.reader.replace(':', '.')}` |" for r in LAYOUTS]
    return "\n".join(rows) + "\n"


def layout(name: str) -> Layout:
    """The record of layout ``name`` (``"auto"`` is not a layout: see ``detect_format``)."""
    if name not in BY_NAME:
        raise InputError(f"unknown format {name!r}; expected one of {', '.join(FORMATS)}",
                         parameter="format")
    return BY_NAME[name]


def detect_format(path: Path, text: str | None = None) -> str:
    """The name of the layout of the file at ``path`` (see the module docstring).

    Raises
    ------
    InputError
        The file is empty, not text, separated by something other than commas, or of no
        known layout.
    """
    probe = Probe(Path(path), text)
    for record in LAYOUTS:
        if record.signature is not None and record.signature(probe):
            return record.name
    if probe.text is None:
        raise probe.error
    if not probe.text.strip():
        raise InputError("empty file; expected a header row and readings", file=path)
    for record in LAYOUTS:
        if record.header is not None and record.header(probe.names):
            return record.name
    check_delimiter(probe.header, path)
    raise InputError(UNKNOWN_FORMAT, file=path, row=1)


def check_delimiter(header: str, path: Path) -> None:
    """Refuse a header separated by semicolons, tabs or pipes: the CSV reader needs commas."""
    for sep, name in ((";", "semicolon"), ("\t", "tab"), ("|", "pipe")):
        if sep in header and "," not in header:
            raise InputError(f"columns are separated by {name}s; expected commas", file=path,
                             row=1)


# Byte-order marks of the Unicode encodings a spreadsheet may save; UTF-8 is the default.
_BOMS = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"),
         (codecs.BOM_UTF8, "utf-8-sig"), (codecs.BOM_UTF16_LE, "utf-16"),
         (codecs.BOM_UTF16_BE, "utf-16"))


def read_text(path: Path) -> str:
    """The whole file as text: UTF-8, or UTF-16/32 when it starts with a byte-order mark.

    Every byte is decoded, so a stray Latin-1 byte anywhere is refused with its row; an
    encoding without a mark (Latin-1, Windows-1252, ...) is never guessed, since a guess
    can silently turn one machine or test name into another.
    """
    try:
        data = Path(path).read_bytes()
    except IsADirectoryError:
        raise InputError("is a folder; expected a readings file", file=path) from None
    except OSError as err:
        raise InputError(f"cannot read file: {err.strerror}", file=path) from None
    encoding = next((enc for bom, enc in _BOMS if data.startswith(bom)), "utf-8-sig")
    if encoding == "utf-8-sig" and b"\x00" in data:
        raise InputError("cannot read file: binary content, expected CSV text", file=path)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as err:
        row = data.count(b"\n", 0, err.start) + 1
        name = encoding.removesuffix("-sig").upper()
        raise InputError(
            f"byte 0x{data[err.start]:02x} at offset {err.start} is not {name} text; save the "
            "file as UTF-8 (Latin-1 or Windows-1252 are not guessed)", file=path,
            row=row) from None
