"""Read any accepted layout into the validated readings frame; write it atomically."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from features.readings.errors import InputError
from features.readings.fileio import atomic_path
from features.readings.formats import FORMATS, detect_format, paper_to_long, read_ecmc, read_table
from features.readings.rtl import read_rtl
from features.readings.validation import validate


def read_readings(path, format: str = "auto") -> pd.DataFrame:
    """Read a readings file in any accepted layout into the validated long frame."""
    path = Path(path)
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; expected one of {', '.join(FORMATS)}",
                         file=path)
    if path.is_dir():
        raise InputError("is a folder; expected a readings file", file=path)
    if not path.is_file():
        raise InputError("cannot read file: no such file", file=path)
    if format == "auto":
        format = detect_format(path)
    if format == "ecmc":
        raw, row_base = read_ecmc(path), None
    elif format == "rtl":
        raw, row_base = read_rtl(path), None
    else:
        raw, row_base = read_table(path)
        if format == "paper":
            raw = paper_to_long(raw, path, row_base)
            row_base = None
    return validate(raw, path, row_base)



def write_readings(frame: pd.DataFrame, path) -> Path:
    """Write a readings frame as CSV or Parquet (by suffix), atomically."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise InputError("unknown output type; expected a .csv or .parquet file name", file=path)
    with atomic_path(path) as tmp:
        if suffix == ".parquet":
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, date_format="%Y-%m-%dT%H:%M:%S.%f%z")
    return path
