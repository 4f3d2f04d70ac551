"""Readers of the input layouts (records in ``features.readings.layouts``), each returning
long readings not yet validated.

- ``canonical``: the readings table itself, CSV or Parquet;
- ``paper``: the wide layout of the backlash paper's Table 2 [BacklashNN], one row per
  target and condition with linear and pendulum deviations forward/reverse;
- ``ecmc``: ``*_ISO230.dat`` files of the ecmc motion-control test scripts;
- ``rtl``: Renishaw ``.rtl`` laser test files (``features.readings.rtl``).
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError, note
from features.readings.layouts import (  # noqa: F401 - detect_format, read_text: their old home
    PAPER_DEV_LIN_F,
    check_delimiter,
    detect_format,
    read_text,
)
from features.readings.validation import (
    MAX_DEVIATION_POS_UNITS,
    ROW,
    check_header,
    looks_absolute,
    to_float,
    to_int,
)

# Paper Table 2 columns: canonical wide names and the spellings accepted for them.
PAPER_COLUMNS = {
    "position_mm": ("position_mm", "pos. [mm]", "pos [mm]", "pos", "position"),
    "dev_lin_f_mm": PAPER_DEV_LIN_F,
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



def read_table(path: Path, text: str | None = None) -> tuple[pd.DataFrame, int]:
    """Read CSV or Parquet as strings/objects; returns the frame and the row number of its
    first data row (2 for CSV, whose header is row 1; 1 for Parquet)."""
    if path.suffix.lower() == ".parquet":
        try:
            frame = pd.read_parquet(path)
        except Exception as err:  # noqa: BLE001 - pyarrow raises many types for a broken file
            raise InputError(f"cannot read Parquet file: {err}", file=path) from None
        check_header([str(c) for c in frame.columns], path)
        row_base = 1
    else:
        frame = _read_plain_csv(path) if text is None else None
        if frame is None:
            frame, header = _read_csv_text(path, text)
        else:
            header = list(frame.columns)
        if frame.shape[1] == 1:
            check_delimiter(frame.columns[0], path)
        frame = _drop_blank_columns(frame, header, path)
        check_header([str(c) for c in frame.columns], path)
        row_base = 2
        # Blank lines are skipped, but every reading keeps the row number of its line.
        blank = _blank_rows(frame)
        frame = frame.assign(**{ROW: np.arange(len(frame)) + row_base}).loc[~blank]
    frame.columns = [str(c).strip() for c in frame.columns]
    if frame.empty:
        raise InputError("no readings: the file has a header but no data rows", file=path)
    return frame, row_base


def _read_csv_text(path: Path, text: str | None) -> tuple[pd.DataFrame, list[str]]:
    """Every cell as text, and the header as written: the general reader, whose errors name
    what is wrong with the file."""
    text = read_text(path) if text is None else text
    if not text.strip():
        raise InputError("empty file; expected a header row and readings", file=path)
    header = next(csv.reader(io.StringIO(text)), [])
    try:
        frame = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False,
                            skipinitialspace=True, skip_blank_lines=False)
    except pd.errors.ParserError as err:
        raise InputError(f"malformed CSV: {err}", file=path) from None
    except pd.errors.EmptyDataError:
        raise InputError("empty file; expected a header row and readings", file=path) from None
    return frame, header


def _read_plain_csv(path: Path) -> pd.DataFrame | None:
    """Every cell as text through Arrow's CSV reader, for the common file: UTF-8 without a
    byte-order mark, no quotes, no space after a delimiter. It reads the
    fleet's files several times faster than pandas and never holds a Python string per cell;
    any other file (or any doubt) returns None and goes to the general reader, which explains
    what is wrong with it."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    try:
        data = path.read_bytes()
    except OSError:
        return None
    end = data.find(b"\n")
    if (end < 0 or data.startswith((b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff"))
            or b"\x00" in data or b'"' in data):
        return None
    names = data[:end].decode("utf-8", "replace").rstrip("\r").split(",")
    if len(names) < 2 or len(set(names)) != len(names) or "" in names:
        return None
    try:  # a blank line becomes a row of empty cells, dropped as blank by the caller
        table = pacsv.read_csv(
            pa.BufferReader(data),
            parse_options=pacsv.ParseOptions(ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(names, pa.string()), strings_can_be_null=False))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    del data
    if table.num_rows == 0 or table.column_names != names:
        return None
    if any(pc.any(pc.starts_with(column, " ")).as_py() for column in table.columns):
        return None  # space after a delimiter: the general reader skips it
    return table.to_pandas()


def _blank_rows(frame: pd.DataFrame) -> np.ndarray:
    """Rows whose every cell is empty or spaces; only rows blank in the first column are
    checked further, so a file without blank lines costs one column's check."""
    if frame.shape[1] == 0:
        return np.ones(len(frame), dtype=bool)
    first = frame.iloc[:, 0].fillna("").str.strip().eq("").to_numpy()
    blank = np.zeros(len(frame), dtype=bool)
    candidates = np.flatnonzero(first)
    if len(candidates):
        rest = frame.iloc[candidates].fillna("")
        blank[candidates] = rest.apply(lambda col: col.str.strip().eq("")).all(axis=1)
    return blank


def read_canonical(path: Path) -> pd.DataFrame:
    """The ``canonical`` layout: the readings table itself (CSV or Parquet)."""
    return read_table(path)[0]


def read_paper(path: Path) -> pd.DataFrame:
    """The ``paper`` layout: the wide Table 2 of the backlash paper, as long readings."""
    wide, row_base = read_table(path)
    return paper_to_long(wide, path, row_base)


def _drop_blank_columns(frame: pd.DataFrame, header: list[str], path: Path) -> pd.DataFrame:
    """Columns without a name (a spreadsheet's trailing commas) are dropped when empty and
    refused when they hold values; duplicate names are refused (pandas would rename them)."""
    names = [h.strip() for h in header]
    if len(names) != frame.shape[1]:
        return frame
    seen: dict[str, int] = {}
    for number, name in enumerate(names, start=1):
        if name and name in seen:
            raise InputError(f"column {name!r} appears twice (columns {seen[name]} and "
                             f"{number}); expected each column once", file=path, row=1,
                             column=name)
        seen.setdefault(name, number)
    keep = []
    for number, (name, col) in enumerate(zip(names, frame.columns), start=1):
        if name:
            keep.append(col)
            continue
        filled = frame[col].astype(str).str.strip().ne("")
        if filled.any():
            raise InputError(f"column {number} has values but no name in the header; expected "
                             "a column name", file=path, row=int(np.flatnonzero(filled)[0]) + 2)
    frame = frame[keep]
    frame.columns = [n for n in names if n]
    return frame


_ECMC_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_ECMC_TARGET = re.compile(r"TGT_DATA\[(\d+)\]\s*=\s*(.*)")
_ECMC_REF = re.compile(r"REF_DATA_(FWD|BWD)\[(\d+),\s*(\d+)\]\s*=\s*(.*)")
_ECMC_UNIT = re.compile(r"UNIT\s*=\s*(.*)")
_ECMC_COUNT = re.compile(r"(CYCLES|POSITIONS)\s*=\s*(\d+)")
_ECMC_SETPOINT = re.compile(r"TGT_SET_PV\s*=\s*(\S*)")
# A part of an ecmc PV's axis name that is a machine axis: one axis letter, alone, after
# "Axis" or before a digit (Z, AxisZ, Axis_Z, Z1); a number (Axis1, M1) names no letter.
_PV_AXIS = re.compile(r"(?:[Aa]xis)?([XYZABC])\d?")


def axis_from_pv(pv: str) -> str | None:
    """The machine axis an ecmc PV's name gives, or None.

    ecmc names an axis's PVs ``<IOC prefix>:<axis name>-<field>`` (``PosSet``, ``PosCmd``,
    ``PosAct``...). The axis name is the record's part before its last ``-``, split at ``-``,
    ``_`` and ``.``; the axis is the one part that is an axis letter (``_PV_AXIS``):
    ``TARGET_DU:Z-PosCmd`` -> Z, ``LAB:Mtr-Y1-PosSet`` -> Y, ``MC:AxisX-PosSet`` -> X. The
    IOC prefix is not read (``TARGET_DU``'s ``DU`` names no axis), nor is a name with parts of
    two axes (``X-Y-PosSet``) or with none (``IOC_TEST:Axis1-PosSet``, ``ecat01:M1-PosSet``,
    ``ec0-s4-EL7211-Enc-PosAct``: axis numbers and terminals).
    """
    record = pv.rsplit(":", 1)[-1]
    name = record.rsplit("-", 1)[0] if "-" in record else record
    found = {m[1] for part in re.split(r"[-_.]", name) if (m := _PV_AXIS.fullmatch(part))}
    return found.pop() if len(found) == 1 else None


def read_ecmc(path: Path, text: str | None = None) -> pd.DataFrame:
    """Parse an ecmc ``*_ISO230.dat`` file. FWD readings are the ``+`` direction.

    Every ``TGT_DATA``/``REF_DATA`` line must hold one finite plain number (no NaN, no unit
    after it); the ``row`` of each reading is its line in the file.
    """
    text = read_text(path) if text is None else text
    targets, refs, unit, declared, setpoint = {}, [], None, {}, ""
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if m := _ECMC_TARGET.fullmatch(line):
            value = _ecmc_number(m[2], path, lineno)
            pos_id = int(m[1])
            if pos_id in targets and targets[pos_id] != value:
                raise InputError(f"TGT_DATA[{pos_id}] is given twice with different values "
                                 f"({targets[pos_id]:g} and {value:g})", file=path, row=lineno)
            targets[pos_id] = value
        elif m := _ECMC_REF.fullmatch(line):
            refs.append((m[1], int(m[2]), int(m[3]), _ecmc_number(m[4], path, lineno), lineno))
        elif m := _ECMC_UNIT.fullmatch(line):
            if unit is not None and unit != m[1].strip().lower():
                raise InputError(f"UNIT is given twice ({unit} and {m[1].strip()}); expected "
                                 "one unit for the file", file=path, row=lineno)
            unit = m[1].strip().lower()
        elif m := _ECMC_COUNT.fullmatch(line):
            declared[m[1]] = (int(m[2]), lineno)
        elif m := _ECMC_SETPOINT.fullmatch(line):
            setpoint = m[1]
        elif line.startswith(("TGT_DATA", "REF_DATA")):
            raise InputError(f"cannot read {line[:40]!r}; expected TGT_DATA[i]=number or "
                             "REF_DATA_FWD/BWD[i,j]=number", file=path, row=lineno)
    if not targets or not refs:
        raise InputError("no TGT_DATA/REF_DATA lines: not an ecmc ISO230 file", file=path)
    unit = unit or "mm"
    scale = {"mm": 1000.0, "um": 1.0, "deg": 3600.0}.get(unit)
    if scale is None:
        raise InputError(f"UNIT={unit}: expected mm, um or deg", file=path)
    ref = pd.DataFrame(refs, columns=["dir", "pos_id", "cycle", "measured", "row"])
    missing = ref.loc[~ref["pos_id"].isin(list(targets))]
    if len(missing):
        pos_id = int(missing["pos_id"].iloc[0])
        raise InputError(f"REF_DATA for position {pos_id} has no TGT_DATA[{pos_id}]",
                         file=path, row=int(missing["row"].iloc[0]))
    _check_declared_counts(ref, targets, declared, path)
    ref["target"] = ref["pos_id"].map(targets)
    stem = path.stem.removesuffix("_ISO230")
    rotary = unit == "deg"
    # Deviations in um (arcsec); readings are converted here so `measured` keeps its unit.
    ref["deviation_um"] = (ref["measured"] - ref["target"]) * scale
    if unit == "um":
        ref["target"] = ref["target"] / 1000.0
        ref["measured"] = ref["measured"] / 1000.0
    axis, named_by = _ecmc_axis(setpoint, rotary, path)
    frame = pd.DataFrame({
        "machine_id": stem, "axis": axis, "test_id": path.stem,
        "method": "linear", "target": ref["target"],
        "direction": np.where(ref["dir"] == "FWD", "+", "-"), "cycle": ref["cycle"],
        "deviation_um": ref["deviation_um"], "measured": ref["measured"], ROW: ref["row"],
    })
    # the header names neither: the axis comes at best from the PV's name, which --axis overrides
    frame.attrs[schema.UNSTATED] = ("machine_id", "axis")
    if named_by:
        frame.attrs[schema.NAMED_BY] = {"axis": named_by}
    return frame


def _ecmc_axis(setpoint: str, rotary: bool, path: Path) -> tuple[str, str]:
    """The axis of an ecmc test and what named it: the set-point PV's axis letter
    (``axis_from_pv``) when it is of the kind the file's UNIT says (deg: rotary); else X (A for
    a rotary axis) and no namer, for ``Selection`` to note."""
    default = "A" if rotary else "X"
    letter = axis_from_pv(setpoint) if setpoint else None
    if letter is None:
        return default, ""
    if schema.is_rotary(letter) != rotary:
        note(f"{path}: the set-point PV TGT_SET_PV={setpoint} names axis {letter}, but UNIT "
             f"{'deg is a rotary' if rotary else 'is a linear'} axis's: its name is not taken")
        return default, ""
    return letter, f"its set-point PV TGT_SET_PV={setpoint}"


def _check_declared_counts(ref: pd.DataFrame, targets: dict, declared: dict,
                           path: Path) -> None:
    """A file that declares POSITIONS or CYCLES must hold exactly that many: fewer means a
    truncated or edited file, whose figures would silently rest on fewer readings."""
    if "POSITIONS" in declared:
        count, lineno = declared["POSITIONS"]
        if len(targets) != count:
            raise InputError(f"POSITIONS={count} but the file has {len(targets)} TGT_DATA "
                             "lines; the file looks truncated or edited", file=path, row=lineno)
    if "CYCLES" in declared:
        count, lineno = declared["CYCLES"]
        per_point = ref.groupby(["pos_id", "dir"], sort=True)["cycle"].nunique()
        wrong = per_point[per_point != count]
        missing = [(p, d) for p in targets for d in ("FWD", "BWD") if (p, d) not in per_point]
        if missing or len(wrong):
            pos_id, way = missing[0] if missing else wrong.index[0]
            found = 0 if missing else int(wrong.iloc[0])
            raise InputError(f"CYCLES={count} but position {pos_id} {way} has {found} cycles; "
                             "the file looks truncated or edited", file=path, row=lineno)


def _ecmc_number(text: str, path: Path, lineno: int) -> float:
    text = text.strip()
    if not re.fullmatch(_ECMC_NUMBER, text):
        raise InputError(f"{text!r} is not a number; expected a plain finite number in the "
                         "file's UNIT (no NaN, no unit after it)", file=path, row=lineno)
    value = float(text)
    if not np.isfinite(value):
        raise InputError(f"{text!r} is too large; expected a finite number", file=path,
                         row=lineno)
    return value


# --------------------------------------------------------------------------- paper layout


def paper_to_long(wide: pd.DataFrame, path: Path, row_base: int) -> pd.DataFrame:
    """Paper Table 2 (one row per target and condition) -> long readings.

    Each wide row holds four readings: linear and pendulum, forward (+) and reverse (-).
    A test is one method at one (visit, speed, dwell, repeat); the cycle index is the
    occurrence count of the position within that test. Deviations are in mm; cells that
    hold absolute positions (Table 2 has such rows) are converted to deviations.
    """
    cols = _paper_columns(wide, path)
    frame = pd.DataFrame({name: wide[src] for name, src in cols.items()})
    frame[ROW] = wide[ROW] if ROW in wide else np.arange(len(frame)) + row_base
    numeric = [c for c in frame.columns if c not in ("visit", "machine_id", "axis", "repeat",
                                                      ROW)]
    for col in numeric:
        frame[col] = to_float(frame[col], path, cols[col], frame[ROW])
    unstated = tuple(c for c in ("machine_id", "axis") if c not in frame)
    frame["machine_id"] = frame.get("machine_id", path.stem)
    frame["axis"] = frame.get("axis", "X")
    frame["visit"] = frame.get("visit", "1")
    frame["repeat"] = (to_int(frame["repeat"], path, cols["repeat"], frame[ROW])
                       if "repeat" in frame else 1)
    if "dwell_s" not in frame:
        frame["dwell_s"] = np.nan
    dev_cols = ["dev_lin_f_mm", "dev_lin_r_mm", "dev_pend_f_mm", "dev_pend_r_mm"]
    _absolute_rows_to_deviations(frame, dev_cols, cols, path)

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
    long = long.sort_values([ROW, "method", "direction"], kind="stable")
    long.attrs[schema.UNSTATED] = unstated
    return long


def _paper_columns(wide: pd.DataFrame, path: Path) -> dict[str, str]:
    """Canonical wide name -> the file's column; two spellings of one column are refused."""
    cols: dict[str, str] = {}
    for name, aliases in PAPER_COLUMNS.items():
        found = [c for c in wide.columns if c.lower() in aliases]
        if len(found) > 1:
            raise InputError(f"columns {found[0]!r} and {found[1]!r} both give {name!r}; "
                             "expected one of them", file=path, row=1, column=found[1])
        if found:
            cols[name] = found[0]
    for name in PAPER_REQUIRED:
        if name not in cols:
            raise InputError(f"missing paper Table-2 column {name!r}", file=path, row=1,
                             column=name)
    return cols


def _absolute_rows_to_deviations(frame: pd.DataFrame, dev_cols: list[str], cols: dict,
                                 path: Path) -> None:
    """Convert rows holding absolute positions (all four cells) to deviations, in place.

    Table 2 holds whole rows of positions; a row where only some cells read like positions,
    or a deviation beyond MAX_DEVIATION_POS_UNITS mm (typically micrometres written in the
    mm columns, 1000x too large), cannot be interpreted and is refused.
    """
    looks = pd.DataFrame({c: looks_absolute(frame[c], frame["position_mm"]) for c in dev_cols})
    partly = looks.any(axis=1) & ~looks.all(axis=1)
    if partly.any():
        i = int(np.flatnonzero(partly)[0])
        col = dev_cols[int(np.flatnonzero(~looks.iloc[i].to_numpy())[0])]
        raise InputError(
            f"{frame[col].iloc[i]:g} is a deviation while other cells of this row are absolute "
            f"positions near {frame['position_mm'].iloc[i]:g} mm; expected one or the other "
            "in a row", file=path, row=int(frame[ROW].iloc[i]), column=cols[col])
    absolute = looks.all(axis=1)
    for col in dev_cols:
        frame.loc[absolute, col] = frame.loc[absolute, col] - frame.loc[absolute, "position_mm"]
        too_large = frame[col].abs() > MAX_DEVIATION_POS_UNITS
        if too_large.any():
            i = int(np.flatnonzero(too_large)[0])
            raise InputError(
                f"deviation {frame[col].iloc[i]:g} mm at position "
                f"{frame['position_mm'].iloc[i]:g} is beyond {MAX_DEVIATION_POS_UNITS:g} mm; "
                "expected mm (micrometres here would be 1000x too large)", file=path,
                row=int(frame[ROW].iloc[i]), column=cols[col])
    if absolute.any():
        note(f"{path}: {4 * int(absolute.sum())} cells of the deviation columns hold absolute "
             "positions; converted to deviations (value - position)")
