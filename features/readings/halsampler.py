"""LinuxCNC ``halsampler`` output and ``halscope`` log exports: what a LinuxCNC machine logs
while an axis moves.

Three text layouts, told apart by their first line:

- **halsampler** (``loadrt sampler cfg=fff`` + ``halsampler > file``): one line per sample of
  the sampler's thread, the pins' values separated by spaces, in the order of ``cfg``; with
  ``halsampler -t`` the first field is the sample number. No header, no time, no period:
  ``period_s`` (the sampler thread's period) must be given, and ``columns`` maps channel
  names to 0-based field numbers (``{"commanded": 1, "motor": 2}``; the name ``sample``
  marks the ``-t`` sample-number field, which then gives the times).
- **halscope CSV** (LinuxCNC 2.10, File > Save log): ``# Sampling period is N ns``, a line of
  channel names separated by ``;``, optional ``# Position:``/``# Scale:`` lines, then one line
  of ``;``-separated values per sample; ``columns`` maps channel names to pin names.
- **halscope legacy** (LinuxCNC up to 2.9): ``Sampling period is N nSec``, then one line per
  sample of ``pin value`` pairs (``axis.0.motor-pos-cmd +1.00000000000000 ...``);
  ``columns`` maps channel names to pin names.

``read_halsampler(path, columns)`` returns the same shape as
``features.readings.camonitor.read_camonitor``: ``time`` (UTC), one float column per channel
name (values exactly as logged, no unit conversion) and ``row`` (the line in the file). The
files state no clock time: sample k is at ``start + k * period``; ``start`` defaults to the
file's modification time minus the samples' duration (halsampler writes as it samples, so
its file ends at its last sample), and a note says so.

Refused, with one line naming file and row (``InputError``): a field that is not a number, a
line with another number of fields, a mapped field or pin the file does not have, sample
numbers going back, a missing or non-positive period.
"""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError, note

_PERIOD = re.compile(r"^#?\s*Sampling period is\s+(\d+)\s*n(?:s|Sec)\b", re.IGNORECASE)


def read_halsampler(path, columns: dict, period_s: float | None = None,
                    start=None) -> pd.DataFrame:
    """Per-sample rows of a halsampler output or halscope log export.

    Parameters
    ----------
    path : str or path-like
        The file.
    columns : dict
        Channel name -> 0-based field number (halsampler) or pin name (halscope).
    period_s : float, optional
        Sample period [s]; required for halsampler output (halscope states its own, and a
        given one must agree with it).
    start : datetime or str, optional
        Time of the first sample (UTC unless it has an offset). Default: the file's
        modification time minus the samples' duration (with a note).

    Returns
    -------
    DataFrame
        ``time`` (datetime, UTC), one float column per channel, ``row`` (line in the file).

    Raises
    ------
    InputError
        See the module docstring.
    """
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as fh:
            head = [fh.readline() for _ in range(4)]
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read file: {err}", file=path) from None
    period = _PERIOD.match(head[0].strip())
    if period is None:
        frame, first_row = _halsampler(path), 1
    elif head[0].lstrip().startswith("#"):
        frame, first_row = _halscope_csv(path, head)
    else:
        frame, first_row = _halscope_legacy(path)
    stated = None if period is None else int(period[1]) * 1e-9
    period_s = _period(path, period_s, stated)
    return _samples(path, frame, columns, period_s, start, first_row)


def _period(path: Path, given: float | None, stated: float | None) -> float:
    if stated is not None and stated <= 0:
        raise InputError(f"sampling period {stated:g} s; expected a positive period", file=path,
                         row=1)
    if given is not None and (not np.isfinite(given) or given <= 0):
        raise InputError(f"{given!r}: expected a positive sample period [s]",
                         parameter="period_s")
    if given is not None and stated is not None and abs(given - stated) > 1e-9 * max(1, stated):
        raise InputError(f"the file states a sampling period of {stated:g} s, not {given:g} s",
                         file=path, parameter="period_s")
    if given is None and stated is None:
        raise InputError("halsampler writes no sample period; expected period_s (the "
                         "sampler thread's period)", file=path, parameter="period_s")
    return stated if given is None else given


def _read(path: Path, **options) -> pd.DataFrame:
    try:
        return pd.read_csv(path, header=None, dtype=str, keep_default_na=False,
                           skip_blank_lines=True, engine="c", **options)
    except pd.errors.ParserError as err:
        found = re.search(r"line (\d+), saw (\d+)", str(err))
        raise InputError("a line has " + (f"{found[2]} fields" if found else "another number "
                         "of fields") + "; expected the same number on every line", file=path,
                         row=int(found[1]) if found else None) from None
    except pd.errors.EmptyDataError:
        raise InputError("no samples; expected lines of numbers", file=path) from None


def _numbers(path: Path, text: pd.DataFrame, first_row: int) -> pd.DataFrame:
    """Every field as float; a field that is not a number is refused with its row."""
    numbers = text.apply(pd.to_numeric, errors="coerce")
    bad = numbers.isna().to_numpy() | ~np.isfinite(numbers.to_numpy(dtype=float))
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(f"{text.iat[i, j]!r} is not a finite number", file=path,
                         row=int(i) + first_row, column=str(text.columns[j]))
    return numbers.astype(float)


def _halsampler(path: Path) -> pd.DataFrame:
    text = _read(path, sep=r"\s+")
    return _numbers(path, text, 1)


def _halscope_csv(path: Path, head: list[str]) -> tuple[pd.DataFrame, int]:
    names = [n.strip() for n in head[1].rstrip("\n").split(";")]
    skip = 2 + sum(1 for line in head[2:4] if line.startswith(("# Position:", "# Scale:")))
    text = _read(path, sep=";", skiprows=skip)
    if text.shape[1] != len(names):
        raise InputError(f"{text.shape[1]} values per line but {len(names)} channel names; "
                         "expected one value per channel", file=path, row=skip + 1)
    text.columns = names
    return _numbers(path, text, skip + 1), skip + 1


def _halscope_legacy(path: Path) -> tuple[pd.DataFrame, int]:
    text = _read(path, sep=r"\s+", skiprows=1)
    if text.shape[1] % 2:
        raise InputError("expected 'pin value' pairs on every sample line", file=path, row=2)
    labels = text.iloc[:, 0::2]
    names = list(labels.iloc[0])
    differ = (labels != names).any(axis=1).to_numpy()
    if differ.any():
        i = int(np.flatnonzero(differ)[0])
        raise InputError(f"pins {list(labels.iloc[i])} differ from the first line's {names}",
                         file=path, row=i + 2)
    values = text.iloc[:, 1::2]
    values.columns = names
    # the legacy writer starts its samples with a line break: its first line is blank
    return _numbers(path, values, 3), 3


def _samples(path: Path, frame: pd.DataFrame, columns: dict, period_s: float, start,
             first_row: int) -> pd.DataFrame:
    keys = {name: _key(path, frame, name, key) for name, key in columns.items()}
    sample_key = keys.pop("sample", None)
    if sample_key is not None:
        number = frame[sample_key].to_numpy()
        back = np.flatnonzero(np.diff(number) <= 0)
        if len(back):
            raise InputError(f"sample number {number[back[0] + 1]:g} after {number[back[0]]:g}; "
                             "expected increasing sample numbers", file=path,
                             row=int(back[0]) + 1 + first_row)
        offsets = (number - number[0]) * period_s
    else:
        offsets = np.arange(len(frame)) * period_s
    if start is None:
        end = dt.datetime.fromtimestamp(path.stat().st_mtime, dt.UTC)
        start = pd.Timestamp(end) - pd.Timedelta(seconds=float(offsets[-1]))
        note(f"{path}: the file states no clock time; samples end at its modification time "
             f"({end:%Y-%m-%d %H:%M:%S} UTC): give start to place them")
    start = pd.Timestamp(start)
    start = start.tz_localize("UTC") if start.tzinfo is None else start.tz_convert("UTC")
    out = pd.DataFrame({"time": start + pd.to_timedelta(offsets, unit="s")})
    for name, key in keys.items():
        out[name] = frame[key].to_numpy()
    out["row"] = np.arange(len(frame)) + first_row
    return out


def _key(path: Path, frame: pd.DataFrame, name: str, key):
    """The frame column a channel maps: a 0-based field number or a pin name."""
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        if not 0 <= key < frame.shape[1]:
            raise InputError(f"channel {name} is field {key}, but lines have {frame.shape[1]} "
                             f"fields (0 to {frame.shape[1] - 1})", file=path,
                             parameter="columns")
        return frame.columns[key]
    if key not in frame.columns:
        raise InputError(f"channel {name} is pin {key!r}, which the file does not log; it logs "
                         f"{', '.join(map(str, frame.columns))}", file=path,
                         parameter="columns")
    return key
