"""Readings in and out: read any accepted layout, validate a frame made by hand, write the
canonical table, or all three at once (``convert``).

>>> import backlash as bl
>>> readings = bl.read("ess_mcu1025_ISO230.dat")          # doctest: +SKIP
>>> fleet = bl.read("fleet/", machine="M01", axis="X")    # doctest: +SKIP
>>> bl.write(readings, "ess.parquet")                     # doctest: +SKIP
>>> bl.convert("table2.csv", "table2.parquet").tests      # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from features.readings import schema
from features.readings.errors import InputError
from pipeline.results import Result
from pipeline.steps.parameters import FORMAT, RAW_LOG, Param, python_only, readings
from pipeline.steps.source import readings_of
from pipeline.workflows import checked

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--out", "{side}/r.csv"],
    {"data": "{two}", "out": "{side}/r.csv"},
)

# convert's table (the runner checks a call of the job against it); read, validate and
# write, plain functions no runner calls, check their own parameters (path, source) in it
PARAMETERS = {
    "data": readings(flag="FILE"),
    "format": FORMAT,
    # its own help: required on the command line, where Python may leave it out (None)
    "out": Param((str, os.PathLike), "output file, .csv or .parquet; never the input file",
                 required=True, output="file"),
    **RAW_LOG,
    "path": python_only(str, os.PathLike),
    "source": python_only(str, os.PathLike),
}


@checked(PARAMETERS, "path", "format", "channels", "reference_scale", "unit")
def read(path, format: str = "auto", *, machine=None, axis=None, since=None, until=None,
         channels=None, reference_scale=None, unit=None):
    """Read a readings file in any accepted layout, or a fleet store, into the validated
    readings frame; optionally only some tests.

    Parameters
    ----------
    path : str or path-like
        A readings file, a store folder or a ``postgresql://`` store URL (``docs/store.md``).
    format : str
        ``"auto"`` (recognise the layout from the file) or a layout name of
        ``features.readings.layouts.LAYOUTS`` (``schema.FORMATS``); a store takes ``"auto"``.
    machine : str or list of str, optional
        Only the tests of these machines (a str is one machine id).
    axis : str or list of str, optional
        Only the tests of these axes (X, Y, Z, A, B, C).
    since, until : str, date or datetime, optional
        Only tests whose ``started_at`` lies on or after ``since`` and on or before ``until``
        (ISO 8601; a date alone includes that whole day; UTC unless the time has an offset).
        Tests without ``started_at`` are left out when either is given (a note says how many).
    channels, reference_scale, unit : optional
        A raw log's channel mapping, reference scale and set-point unit
        (``format="camonitor"``; see ``convert``).

    Returns
    -------
    DataFrame
        One row per reading, the columns of ``docs/data-contract.md`` (deviations in um,
        arcsec for rotary axes); ``attrs["source"]`` is the file or the store (a URL without
        its password), followed by the filters in parentheses. A store's tests come sorted by
        machine, axis, visit and test_id.

    Raises
    ------
    InputError
        The file or store cannot be read, breaks the readings contract (naming file, row and
        column), or no test matches the filters.
    """
    from features.readings.selection import selection

    raw = {"channels": channels, "reference_scale": reference_scale, "unit": unit}
    chosen = selection(machine=machine, axis=axis, since=since, until=until)
    return readings_of(path, format, "path", chosen, raw)


@checked(PARAMETERS, "source")
def validate(frame, source: str = "<memory>"):
    """Check and normalise a readings frame built in code, as ``read`` does for a file.

    Parameters
    ----------
    frame : DataFrame
        Long readings with the columns of ``docs/data-contract.md`` (aliases and
        ``measured`` instead of ``deviation_um`` accepted, as in a file).
    source : str
        The name errors and notes give the frame (rows count from 1).

    Returns
    -------
    DataFrame
        The validated readings frame (a new frame; ``frame`` is not changed).
    """
    import pandas as pd

    from features.readings.validation import validate as validate_frame

    if not isinstance(frame, pd.DataFrame):
        raise TypeError(f"frame must be a pandas DataFrame; got {type(frame).__name__}")
    return validate_frame(frame, Path(source), None)


@checked(PARAMETERS, "path")
def write(readings, path) -> Path:
    """Write validated readings as CSV or Parquet (by the suffix of ``path``), atomically.

    Raises
    ------
    InputError
        ``readings`` is not a validated readings frame, or ``path`` is not a .csv or .parquet
        name or cannot be written.
    """
    from features.readings.io import write_readings
    from features.readings.validation import check_readings

    return write_readings(check_readings(readings), path)


@dataclass
class ConvertResult(Result):
    """Validated readings and where they were written.

    Attributes
    ----------
    readings : DataFrame
        The validated readings.
    tests : int
        Number of tests (machine, axis, visit, test_id) in them.
    out : Path or None
        The file written by ``convert`` (None until written).
    """

    readings: object  # pandas.DataFrame
    tests: int
    out: Path | None = None

    def write(self, out) -> dict[str, Path]:
        """Write the readings to ``out``: a .csv or .parquet file name, or a folder (an
        existing one or a name without suffix: then ``readings.csv`` inside it)."""
        out = Path(out)
        if out.is_dir() or not out.suffix:
            out = out / "readings.csv"
        self.out = write(self.readings, out)
        self.files["readings"] = self.out
        return self.files

    def to_dict(self) -> dict:
        return {"readings": len(self.readings), "tests": self.tests,
                "out": None if self.out is None else str(self.out)}


def convert(data, out=None, format: str = "auto", channels=None, reference_scale=None,
            unit=None) -> ConvertResult:
    """Read a readings file in any accepted layout, validate it and write the canonical table.

    Parameters
    ----------
    data : str, path-like or DataFrame
        The readings file (or a frame ``read`` returned).
    out : str or path-like, optional
        Output file, .csv or .parquet; never the input file. None: nothing written (see
        ``ConvertResult.write``).
    format : str
        Input layout, ``"auto"`` to recognise it.
    channels : str or dict, optional
        A ``camonitor`` log's PVs: ``"target=PV,reference=PV,test=PV"`` or a dict (``test``
        optional: without it the approaches are the settled stops at each target). None:
        inferred from ecmc's PV names (``...-PosSet``, ``...TestNumber``, one other PV).
    reference_scale : float or (float, float), optional
        A ``camonitor`` log's gear ratio and offset [mm] from the reference PV to axis
        coordinates (``measured = scale * reference + offset``). None: fitted to the set
        points (a note gives them; see ``features.readings.approaches``).
    unit : str, optional
        A ``camonitor`` log's set-point unit: ``"mm"``, ``"um"`` or ``"deg"`` (a rotary axis).
        None: deg when the set-point PV names an axis A, B or C, else mm.

    Returns
    -------
    ConvertResult
    """
    raw = {"channels": channels, "reference_scale": reference_scale, "unit": unit}
    # realpath, not Path.resolve: a symbolic-link loop must reach the reader's one-line error,
    # not raise RuntimeError here.
    if (out is not None and isinstance(data, (str, os.PathLike))
            and os.path.realpath(out) == os.path.realpath(data)):
        raise InputError("is the input file; expected a new file name (the original is "
                         "kept)", file=out, parameter="out")
    readings = readings_of(data, format, options=raw)
    tests = readings.groupby(list(schema.TEST_KEYS)).ngroups
    result = ConvertResult(readings=readings, tests=tests)
    if out is not None:  # exactly this file (a name without suffix is refused, not a folder)
        result.out = result.files["readings"] = write(readings, out)
    return result
