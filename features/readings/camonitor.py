"""EPICS ``camonitor`` logs: what an EPICS/ecmc motion controller logs while an axis moves.

``camonitor PV1 PV2 ... > log`` writes one line per value change of any of its process
variables (PVs), the PVs interleaved::

    IOC_TEST:Axis1-PosSet          2021-11-10 13:45:57.123456 15.2
    IOC_TEST:m0s012-Enc01-PosAct   2021-11-10 13:45:57.133456 15.0931  HIGH MINOR
    IOC_TEST:TestNumber            2021-11-10 13:45:57.143456 1101

that is ``PV date time value [status severity]``: the alarm fields appear only while the PV
is in alarm. A PV is logged only when its value changes, so a PV's value at any time is the
value it was last logged with. The first line of each PV is its value when ``camonitor``
connected, stamped with the time of its last change, so it may be older than lines above it:
times run forward within each PV, not across PVs. Lines ``PV *** ...`` (``*** disconnected``,
``*** Not connected``) are connection events and ``PV <undefined> ...`` a PV never processed:
neither holds a value, so they are left out with a note. A value logged with alarm
severity ``INVALID`` is not a measurement either (``valid_values``): left out, counted.

Two readers:

- ``parse_camonitor(path)``: the long frame, one row per line: ``pv``, ``time`` (UTC),
  ``value`` (float, NaN when the line's value is not a number), ``status``, ``severity``
  (empty when not in alarm) and ``row`` (line number in the file).
- ``read_camonitor(path, channels)``: per-sample rows of the PVs ``channels`` maps
  (``{"reference": "IOC_TEST:m0s012-Enc01-PosAct", ...}``): ``time`` (UTC) and one column
  per channel name holding each PV's last logged value, forward-filled, exactly as logged
  (no unit conversion). This is what traces (``backlash monitor``) and ISO 230-2 approach
  extraction (``features.readings.approaches``) are built from.

camonitor writes the logging host's wall-clock time without a zone; it is taken as UTC
(``tz`` names another zone). Refused, with one line naming file and row (``InputError``): a
line that is not ``PV date time value [status severity]``, a time going back within one PV,
a mapped PV never logged or logged with a value that is not a number.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError, note

# Fields of a camonitor line; status and severity only while the PV is in alarm.
FIELDS = ("pv", "date", "clock", "value", "status", "severity")
# The first line of a camonitor log: a PV name, a date, a time of day with fractions.
LINE = re.compile(r"^\S+\s+\d{4}-\d{2}-\d{2}\s+\d{2}:\d{2}:\d{2}(\.\d+)?\s+\S+")
_TIME_FORMAT = "%Y-%m-%d %H:%M:%S.%f"


def looks_like_camonitor(text: str) -> bool:
    """Whether the first non-blank line of ``text`` is a camonitor value line."""
    first = next((line for line in text.splitlines() if line.strip()), "")
    return bool(LINE.match(first.strip()))


def parse_camonitor(path, tz: str = "UTC") -> pd.DataFrame:
    """Every value line of a camonitor log as one row.

    Parameters
    ----------
    path : str or path-like
        The log.
    tz : str
        Time zone of the logged wall-clock times (camonitor writes none).

    Returns
    -------
    DataFrame
        ``pv`` (str), ``time`` (datetime, UTC), ``value`` (float; NaN when not a number),
        ``text`` (the value as written), ``status``, ``severity`` (str, "" when not in alarm)
        and ``row`` (int, line in the file), in file order.

    Raises
    ------
    InputError
        The file is not a camonitor log, or a line is not ``PV date time value [status
        severity]``, naming its row.
    """
    path = Path(path)
    try:
        lines = pd.read_csv(path, sep=r"\s+", header=None, names=FIELDS, dtype=str,
                            skip_blank_lines=False, keep_default_na=False, engine="c",
                            encoding="utf-8")
    except pd.errors.ParserError as err:
        found = re.search(r"line (\d+), saw (\d+)", str(err))
        where = {"row": int(found[1])} if found else {}
        raise InputError("expected 'PV date time value [status severity]' (a value without "
                         "spaces)" + (f"; the line has {found[2]} fields" if found else ""),
                         file=path, **where) from None
    except pd.errors.EmptyDataError:
        raise InputError("empty file; expected camonitor lines 'PV date time value'",
                         file=path) from None
    except UnicodeDecodeError as err:
        raise InputError(f"not UTF-8 text ({err.reason}); expected a camonitor log",
                         file=path) from None
    lines["row"] = np.arange(1, len(lines) + 1)
    lines = lines[lines["pv"] != ""]
    no_value = lines["date"].str.startswith(("***", "<undefined>"))
    if no_value.any():
        note(f"{path}: {int(no_value.sum())} lines 'PV *** ...' (connection events) or 'PV "
             "<undefined> ...' (never processed) hold no value; left out")
        lines = lines[~no_value]
    if lines.empty:
        raise InputError("no value lines; expected camonitor lines 'PV date time value'",
                         file=path)
    time = pd.to_datetime(lines["date"] + " " + lines["clock"], format=_TIME_FORMAT,
                          errors="coerce")
    bad = time.isna() | (lines["value"] == "")
    if bad.any():
        first = lines.loc[bad].iloc[0]
        shown = " ".join(str(first[f]) for f in FIELDS[:4] if first[f])
        raise InputError(f"{shown[:80]!r} is not 'PV date time value'; expected a date "
                         "YYYY-MM-DD, a time HH:MM:SS.ffffff and a value", file=path,
                         row=int(first["row"]))
    return pd.DataFrame({
        "pv": lines["pv"].to_numpy(),
        "time": time.dt.tz_localize(tz).dt.tz_convert("UTC").array,
        "value": pd.to_numeric(lines["value"], errors="coerce").to_numpy(dtype=float),
        "text": lines["value"].to_numpy(),
        "status": lines["status"].to_numpy(), "severity": lines["severity"].to_numpy(),
        "row": lines["row"].to_numpy()})


def parse_channels(text: str, parameter: str = "channels") -> dict[str, str]:
    """``"target=PV,reference=PV"`` -> ``{"target": "PV", "reference": "PV"}``.

    Raises
    ------
    InputError
        An entry is not ``name=PV``, or a name is given twice.
    """
    channels: dict[str, str] = {}
    for entry in filter(None, (e.strip() for e in str(text).split(","))):
        name, sep, pv = (part.strip() for part in entry.partition("="))
        if not sep or not name or not pv or any(c.isspace() for c in pv):
            raise InputError(f"{entry!r} is not name=PV; expected e.g. "
                             "target=IOC:Axis1-PosSet,reference=IOC:Enc-PosAct",
                             parameter=parameter)
        if name in channels:
            raise InputError(f"channel {name!r} is given twice", parameter=parameter)
        channels[name] = pv
    if not channels:
        raise InputError("no channels; expected name=PV pairs separated by commas",
                         parameter=parameter)
    return channels


def read_camonitor(path, channels: dict[str, str], tz: str = "UTC",
                   lines: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per-sample rows of the PVs ``channels`` maps, each PV's value forward-filled.

    Parameters
    ----------
    path : str or path-like
        The camonitor log.
    channels : dict of str to str
        Channel name -> PV name, e.g. ``{"commanded": "IOC:Axis1-PosSet", "motor":
        "IOC:Axis1-PosAct", "load": "IOC:ec0-s4-EL7211-Enc-PosAct"}``.
    tz : str
        Time zone of the logged times (camonitor writes none; default UTC).
    lines : DataFrame, optional
        ``parse_camonitor(path, tz)`` when the caller already has it.

    Returns
    -------
    DataFrame
        One row per logged line of a mapped PV, in time order (file order among equal times),
        from the first time every channel has a value: ``time`` (datetime, UTC), one float
        column per channel name (its PV's last logged value, exactly as logged: no unit
        conversion) and ``row`` (the line that made the row). ``attrs["pvs"]`` is
        ``channels``.

    Raises
    ------
    InputError
        A mapped PV is never logged (the PVs the file holds are named), logs a value that is
        not a number, or its time goes back (naming the row).
    """
    path = Path(path)
    lines = parse_camonitor(path, tz) if lines is None else lines
    logged = set(lines["pv"].unique())
    for name, pv in channels.items():
        if pv not in logged:
            raise InputError(f"PV {pv!r} (channel {name}) is never logged; the file logs "
                             f"{', '.join(sorted(logged))}", file=path)
    by_pv = {pv: name for name, pv in channels.items()}
    if len(by_pv) != len(channels):
        raise InputError("two channels name the same PV; expected one PV per channel",
                         file=path, parameter="channels")
    mine = valid_values(lines[lines["pv"].isin(list(by_pv))], path, by_pv)
    _check_numbers(mine, path, by_pv)
    check_time_order(mine, path)
    mine = mine.sort_values("time", kind="stable")
    out = pd.DataFrame({"time": mine["time"].array, "row": mine["row"].to_numpy()})
    pvs = mine["pv"].to_numpy()
    values = mine["value"].to_numpy()
    for name, pv in channels.items():
        out[name] = pd.Series(np.where(pvs == pv, values, np.nan)).ffill().to_numpy()
    out = out[out[list(channels)].notna().all(axis=1)].reset_index(drop=True)
    out = out[["time", *channels, "row"]]
    out.attrs["pvs"] = dict(channels)
    return out


def valid_values(lines: pd.DataFrame, path, by_pv: dict[str, str]) -> pd.DataFrame:
    """``lines`` without the values logged with alarm severity ``INVALID``.

    EPICS marks a value INVALID when the record could not read its input (a dropped
    EtherCAT frame, a sensor out of range, a lost link): the number it carries is whatever
    was left in the record, not a measurement. Such lines are dropped, counted per channel in
    a note; the PV keeps its last valid value until its next valid line.
    """
    invalid = lines["severity"].to_numpy() == "INVALID"
    if invalid.any():
        counts = lines.loc[invalid, "pv"].value_counts()
        each = ", ".join(f"{n} of {by_pv.get(pv, pv)} ({pv})" for pv, n in counts.items())
        note(f"{path}: {int(invalid.sum())} values logged with alarm severity INVALID are not "
             f"measurements; left out ({each})")
        lines = lines[~invalid]
    return lines


def _check_numbers(lines: pd.DataFrame, path: Path, by_pv: dict[str, str]) -> None:
    bad = ~np.isfinite(lines["value"].to_numpy())
    if bad.any():
        first = lines.iloc[int(np.flatnonzero(bad)[0])]
        raise InputError(f"PV {first['pv']} (channel {by_pv[first['pv']]}) logs "
                         f"{first['text']!r}; expected a finite number", file=path,
                         row=int(first["row"]))


def check_time_order(lines: pd.DataFrame, path: Path) -> None:
    """Times must not go back within one PV (across PVs they may: see the module)."""
    codes = pd.factorize(lines["pv"])[0]
    order = np.argsort(codes, kind="stable")
    times = lines["time"].array.asi8[order]
    back = (np.diff(times) < 0) & (np.diff(codes[order]) == 0)
    if back.any():
        i = order[int(np.flatnonzero(back)[0]) + 1]
        line = lines.iloc[i]
        when = line["time"].strftime("%Y-%m-%d %H:%M:%S.%f")
        raise InputError(f"time goes back for PV {line['pv']} ({when} after a later time); "
                         "expected the times of a PV in order", file=path,
                         row=int(line["row"]))
