"""The accepted input layouts besides the canonical table, each turned into long readings.

- ``canonical``: the readings table itself, CSV or Parquet;
- ``paper``: the wide layout of the backlash paper's Table 2 (seed 004), one row per
  target and condition with linear and pendulum deviations forward/reverse;
- ``ecmc``: ``*_ISO230.dat`` files of the ecmc motion-control test scripts;
- ``rtl``: Renishaw ``.rtl`` laser test files (``features.readings.rtl``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.rtl import looks_like_rtl
from features.readings.validation import looks_absolute, to_float, warn

FORMATS = ("auto", "canonical", "paper", "ecmc", "rtl")

# Paper Table 2 columns: canonical wide names and the spellings accepted for them.
PAPER_COLUMNS = {
    "position_mm": ("position_mm", "pos. [mm]", "pos [mm]", "pos", "position"),
    "dev_lin_f_mm": ("dev_lin_f_mm", "dev_lin_f [mm]", "dev_lin_f"),
    "dev_lin_r_mm": ("dev_lin_r_mm", "dev_lin_r [mm]", "dev_lin_r"),
    "dev_pend_f_mm": ("dev_pend_f_mm", "dev_pend_f [mm]", "dev_pend_f"),
    "dev_pend_r_mm": ("dev_pend_r_mm", "dev_pend_r [mm]", "dev_pend_r"),
    "speed_mm_min": ("speed_mm_min", "speed [mm/min]", "speed", "feed_mm_min"),
    "dwell_s": ("dwell_s", "dwell [s]", "dwell"),
    "t_machine_c": ("t_machine_c", "t_m [°c]", "t_m", "machine_temp_c"),
    "t_ambient_c": ("t_ambient_c", "t_e [°c]", "t_e", "ambient_temp_c"),
    "pressure_hpa": ("pressure_hpa", "p [hpa]", "pressure"),
    "humidity_pct": ("humidity_pct", "rh [%]", "humidity"),
    "repeat": ("repeat",),
    "visit": ("visit",),
    "machine_id": ("machine_id",),
    "axis": ("axis",),
}
PAPER_REQUIRED = ("position_mm", "dev_lin_f_mm", "dev_lin_r_mm", "dev_pend_f_mm",
                  "dev_pend_r_mm", "speed_mm_min")
PAPER_TO_SCHEMA = {"speed_mm_min": "feed_mm_min", "t_machine_c": "machine_temp_c",
                   "t_ambient_c": "ambient_temp_c"}



def detect_format(path: Path) -> str:
    if path.suffix.lower() == ".parquet":
        return "canonical"
    if looks_like_rtl(path):  # before the UTF-8 check: .rtl files may be Latin-1
        return "rtl"
    head = _head(path)
    if not head.strip():
        raise InputError("empty file; expected a header row and readings", file=path)
    if "TGT_DATA[" in head or "REF_DATA_" in head:
        return "ecmc"
    header = head.splitlines()[0].lower() if head.strip() else ""
    names = {c.strip().strip('"') for c in header.split(",")}
    if {"direction", "method"} <= names:
        return "canonical"
    if any(alias in names for alias in PAPER_COLUMNS["dev_lin_f_mm"]):
        return "paper"
    _check_delimiter(header, path)
    raise InputError(
        "unknown format: expected a readings table (columns machine_id, axis, test_id, method, "
        "target, direction, cycle, deviation_um), a paper Table-2 file (Dev_lin_f ...) "
        "or an ecmc *_ISO230.dat file", file=path, row=1)


def _head(path: Path, size: int = 8192) -> str:
    try:
        with open(path, "rb") as fh:
            data = fh.read(size)
    except OSError as err:
        raise InputError(f"cannot read file: {err.strerror}", file=path) from None
    if b"\x00" in data:
        raise InputError("cannot read file: binary content, expected CSV text", file=path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError("cannot read file: not UTF-8 text", file=path) from None


def _check_delimiter(header: str, path: Path) -> None:
    for sep, name in ((";", "semicolon"), ("\t", "tab"), ("|", "pipe")):
        if sep in header and "," not in header:
            raise InputError(f"columns are separated by {name}s; expected commas", file=path,
                             row=1)


def read_table(path: Path) -> tuple[pd.DataFrame, int]:
    """Read CSV or Parquet as strings/objects; returns the frame and the row number of its
    first data row (2 for CSV, whose header is row 1; 1 for Parquet)."""
    if path.suffix.lower() == ".parquet":
        try:
            frame = pd.read_parquet(path)
        except Exception as err:  # noqa: BLE001 - pyarrow raises many types for a broken file
            raise InputError(f"cannot read Parquet file: {err}", file=path) from None
        row_base = 1
    else:
        head = _head(path)
        if not head.strip():
            raise InputError("empty file; expected a header row and readings", file=path)
        try:
            frame = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True,
                                encoding="utf-8-sig")
        except pd.errors.ParserError as err:
            raise InputError(f"malformed CSV: {err}", file=path) from None
        except pd.errors.EmptyDataError:
            raise InputError("empty file; expected a header row and readings",
                             file=path) from None
        if frame.shape[1] == 1:
            _check_delimiter(frame.columns[0], path)
        row_base = 2
    frame.columns = [str(c).strip() for c in frame.columns]
    if frame.empty:
        raise InputError("no readings: the file has a header but no data rows", file=path)
    return frame, row_base


def read_ecmc(path: Path) -> pd.DataFrame:
    """Parse an ecmc ``*_ISO230.dat`` file. FWD readings are the ``+`` direction."""
    text = _head(path, size=50_000_000)
    targets, refs, unit = {}, [], "mm"
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if m := re.fullmatch(r"TGT_DATA\[(\d+)\]\s*=\s*(\S+)", line):
            targets[int(m[1])] = _ecmc_number(m[2], path, lineno)
        elif m := re.fullmatch(r"REF_DATA_(FWD|BWD)\[(\d+),(\d+)\]\s*=\s*(\S+)", line):
            refs.append((m[1], int(m[2]), int(m[3]), _ecmc_number(m[4], path, lineno)))
        elif m := re.fullmatch(r"UNIT\s*=\s*(\S+)", line):
            unit = m[1].lower()
    if not targets or not refs:
        raise InputError("no TGT_DATA/REF_DATA lines: not an ecmc ISO230 file", file=path)
    scale = {"mm": 1000.0, "um": 1.0, "deg": 3600.0}.get(unit)
    if scale is None:
        raise InputError(f"UNIT={unit}: expected mm, um or deg", file=path)
    ref = pd.DataFrame(refs, columns=["dir", "pos_id", "cycle", "measured"])
    missing = sorted(set(ref["pos_id"]) - set(targets))
    if missing:
        raise InputError(f"REF_DATA for position {missing[0]} has no TGT_DATA[{missing[0]}]",
                         file=path)
    ref["target"] = ref["pos_id"].map(targets)
    stem = path.stem.removesuffix("_ISO230")
    rotary = unit == "deg"
    # Deviations in um (arcsec); readings are converted here so `measured` keeps its unit.
    ref["deviation_um"] = (ref["measured"] - ref["target"]) * scale
    if unit == "um":
        ref["target"] = ref["target"] / 1000.0
        ref["measured"] = ref["measured"] / 1000.0
    return pd.DataFrame({
        "machine_id": stem, "axis": "A" if rotary else "X", "test_id": path.stem,
        "method": "linear", "target": ref["target"],
        "direction": np.where(ref["dir"] == "FWD", "+", "-"), "cycle": ref["cycle"],
        "deviation_um": ref["deviation_um"], "measured": ref["measured"],
    })


def _ecmc_number(text: str, path: Path, lineno: int) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{text!r} is not a number", file=path, row=lineno) from None


# --------------------------------------------------------------------------- paper layout


def paper_to_long(wide: pd.DataFrame, path: Path, row_base: int) -> pd.DataFrame:
    """Paper Table 2 (one row per target and condition) -> long readings.

    Each wide row holds four readings: linear and pendulum, forward (+) and reverse (-).
    A test is one method at one (visit, speed, dwell, repeat); the cycle index is the
    occurrence count of the position within that test. Deviations are in mm; cells that
    hold absolute positions (Table 2 has such rows) are converted to deviations.
    """
    lookup = {c.lower(): c for c in wide.columns}
    cols = {}
    for name, aliases in PAPER_COLUMNS.items():
        found = next((lookup[a] for a in aliases if a in lookup), None)
        if found is not None:
            cols[name] = found
    for name in PAPER_REQUIRED:
        if name not in cols:
            raise InputError(f"missing paper Table-2 column {name!r}", file=path, row=1,
                             column=name)
    frame = pd.DataFrame({name: wide[src] for name, src in cols.items()})
    numeric = [c for c in frame.columns if c not in ("visit", "machine_id", "axis")]
    for col in numeric:
        frame[col] = to_float(frame[col], path, cols[col], row_base)
    frame["row"] = np.arange(len(frame)) + row_base
    frame["machine_id"] = frame.get("machine_id", path.stem)
    frame["axis"] = frame.get("axis", "X")
    frame["visit"] = frame.get("visit", "1")
    frame["repeat"] = frame["repeat"].astype(int) if "repeat" in frame else 1
    if "dwell_s" not in frame:
        frame["dwell_s"] = np.nan

    dev_cols = ["dev_lin_f_mm", "dev_lin_r_mm", "dev_pend_f_mm", "dev_pend_r_mm"]
    n_absolute = 0
    for col in dev_cols:
        absolute = looks_absolute(frame[col], frame["position_mm"])
        n_absolute += int(absolute.sum())
        frame.loc[absolute, col] = frame.loc[absolute, col] - frame.loc[absolute, "position_mm"]
    if n_absolute:
        warn(f"{path}: {n_absolute} cells of the deviation columns hold absolute positions; "
             "converted to deviations (value - position)")

    conditions = ["machine_id", "axis", "visit", "speed_mm_min", "dwell_s", "repeat"]
    frame["cycle"] = frame.groupby(conditions + ["position_mm"], dropna=False).cumcount() + 1
    parts = []
    for col, method, direction in zip(dev_cols, ("linear", "linear", "pendulum", "pendulum"),
                                      ("+", "-", "+", "-")):
        part = frame.drop(columns=dev_cols).assign(
            method=method, direction=direction, deviation_um=frame[col] * 1000.0)
        parts.append(part)
    long = pd.concat(parts, ignore_index=True)
    dwell = long["dwell_s"].map(lambda v: "" if pd.isna(v) else f"-D{v:g}")
    long["test_id"] = (long["method"].str[:3] + "-F" + long["speed_mm_min"].map("{:g}".format)
                       + dwell + "-R" + long["repeat"].astype(str))
    long = long.rename(columns={"position_mm": "target", **PAPER_TO_SCHEMA})
    return long.sort_values(["row", "method", "direction"], kind="stable")
