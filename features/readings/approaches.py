"""ISO 230-2 approach readings from a controller's raw log (``--format camonitor``).

An ISO 230-2 run [ISO230-2] moves the axis to each target P_i from both directions, cycle
after cycle, and reads the reference (a laser, a linear scale) once the axis has settled. A
raw log holds that run as time series: the set point (``target`` channel), the reference
(``reference``) and, in ecmc's test scripts, a test number (``test``). This module finds the
approaches in the series (``read_camonitor``'s per-sample frame) and makes them readings:

- **with test numbers** (``from_test_numbers``): ecmc numbers each approach ``d c pp``:
  direction digit d (1 forward = ``+``, 2 backward = ``-``), cycle digit c, two-digit
  position index pp (1101 = forward, cycle 1, position 1). The reading is the reference value
  logged last before the test number changes (or the log ends); the target is the set point
  then. Other test numbers (0 between tests, ecmc's limit-switch and resolver tests) are not
  approaches.
- **without them** (``from_stops``): a stop is a set point held for at least ``dwell_s``; its
  direction is the side it came from (the last set point farther than ``tolerance``), its
  reading the reference logged last before the set point moves on. Stops are grouped into
  targets (set points within ``tolerance`` of each other); only targets stopped at from both
  directions are ISO targets (an overrun or parking position is reached one way only), and
  the cycle is the count of stops at a target and direction so far.

The reference is mapped to axis coordinates (``to_readings``): ``measured = scale * reference
+ offset`` [in the set point's unit] with ``reference_scale = (scale, offset)``; without it the gear ratio and
offset are fitted to the set points by least squares, as ecmc's own report does, and
reported in a note. A fitted ratio takes up the reference's scale and zero, and with them the
axis's linear positioning error and mean deviation: reversal values and repeatability keep
(up to the ratio), E and M lose their linear part. Give the scale when it is known.

The axis is named from the set-point PV ``IOC:RECORD-...`` (ecmc's ``IOC_TEST:Axis1-PosSet``):
a record named X, Y, Z, A, B or C is that axis of machine ``IOC``; any other record
(``Axis1``, ``M1``) is machine ``IOC:RECORD``, axis X, marked as not stated so that ``--axis``
names it (``docs/input-formats.md``). The set point is in mm unless ``unit`` says ``um`` or
``deg`` (a rotary axis: A, or the axis the PV names); an axis A, B or C is in deg.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.camonitor import parse_camonitor, parse_channels, read_camonitor
from features.readings.errors import InputError, note
from features.readings.validation import ROW

# Channels an ISO 230-2 run's log maps; ``test`` is optional (then stops are found).
CHANNELS = ("target", "reference", "test")
REQUIRED = ("target", "reference")
# Default minimum hold of the set point that makes a stop [s] (ISO 230-2 dwells are seconds).
DWELL_S = 1.0
# Stops whose set points are this close are one target [mm].
TOLERANCE_MM = 0.005
# Set points of one position index may differ by this much [mm] (float round-off).
SAME_TARGET_MM = 1e-6
# Units the set point may be logged in: factor to the readings' mm (deg), rotary or not.
UNITS = {"mm": (1.0, False), "um": (1e-3, False), "deg": (1.0, True)}
_RECORD = re.compile(r"^(?P<ioc>[^:]+):(?P<record>[^-:.]+)[-:.]")


def read_camonitor_readings(path, channels=None, reference_scale=None, unit: str | None = None,
                            dwell_s: float = DWELL_S, tz: str = "UTC") -> pd.DataFrame:
    """The ``camonitor`` layout: the approach readings of an ISO 230-2 run in a raw log.

    Parameters
    ----------
    path : str or path-like
        The camonitor log.
    channels : dict or str, optional
        ``{"target": PV, "reference": PV, "test": PV}`` or ``"target=PV,reference=PV,..."``
        (``test`` optional). None: the PV ending ``TestNumber`` is ``test``, the one ending
        ``-PosSet`` is ``target`` and the only other PV is ``reference``.
    reference_scale : float or (float, float), optional
        Gear ratio and offset [mm] from reference to axis coordinates (``measured = scale *
        reference + offset``, in ``unit``); a float is the ratio with offset 0. None: fitted
        (a note says the result).
    unit : str, optional
        Unit of the set point and of axis coordinates: ``mm``, ``um`` or ``deg`` (a rotary
        axis). None: ``deg`` when the set-point PV names an axis A, B or C, else ``mm``.
    dwell_s : float
        Minimum hold of the set point that makes a stop [s] (without test numbers).
    tz : str
        Time zone of the logged times.

    Returns
    -------
    DataFrame
        Long readings, not yet validated (``features.readings.validation``).
    """
    path = Path(path)
    lines = parse_camonitor(path, tz)
    channels = _channels(channels, lines, path)
    machine, axis, record = _names(channels["target"])
    factor, rotary = _unit(unit, axis, path)
    samples = read_camonitor(path, channels, tz, lines=lines)
    samples["target"] *= factor  # to mm (deg): the tolerances are in mm
    if "test" in channels:
        found = from_test_numbers(samples, path)
    else:
        found = from_stops(samples, path, dwell_s)
    readings = to_readings(found, path, _reference_map(found, path, reference_scale, factor))
    stated = axis is not None
    readings = readings.assign(machine_id=machine, axis=axis if stated else ("A" if rotary else "X"),
                               test_id=f"{record}-{found['started'].min():%Y-%m-%dT%H:%M:%S}")
    if rotary:  # deviations of a rotary axis are in arcsec
        readings["deviation_um"] *= 3600.0 / 1000.0
    if not stated:
        readings.attrs[schema.UNSTATED] = ("axis",)
    return readings


def _unit(unit: str | None, axis: str | None, path: Path) -> tuple[float, bool]:
    """(factor to mm or deg, rotary) of the set point's unit; a unit that contradicts the axis
    the PV names is refused."""
    named_rotary = axis is not None and axis in schema.ROTARY_AXES
    unit = unit if unit is not None else ("deg" if named_rotary else "mm")
    if unit not in UNITS:
        raise InputError(f"unknown unit {unit!r}; expected mm, um or deg", parameter="unit")
    factor, rotary = UNITS[unit]
    if axis is not None and rotary != named_rotary:
        raise InputError(f"unit {unit} but the set-point PV names axis {axis}; expected "
                         f"{'deg' if named_rotary else 'mm or um'}", file=path,
                         parameter="unit")
    return factor, rotary


def _channels(channels, lines: pd.DataFrame, path: Path) -> dict[str, str]:
    """Check a given mapping, or infer ecmc's usual one from the PV names."""
    if isinstance(channels, str):
        channels = parse_channels(channels)
    if channels is None:
        pvs = list(dict.fromkeys(lines["pv"]))
        test = [pv for pv in pvs if pv.endswith("TestNumber")]
        target = [pv for pv in pvs if pv.endswith("-PosSet")]
        rest = [pv for pv in pvs if pv not in test + target]
        if len(test) > 1 or len(target) != 1 or len(rest) != 1:
            raise InputError(f"cannot tell which PV is which among {', '.join(pvs)}; "
                             "expected --channels target=PV,reference=PV[,test=PV]", file=path,
                             parameter="channels")
        channels = {"target": target[0], "reference": rest[0], **({"test": test[0]} if test
                                                                   else {})}
    unknown = [name for name in channels if name not in CHANNELS]
    if unknown:
        raise InputError(f"unknown channel {unknown[0]!r}; expected target, reference and "
                         "optionally test", parameter="channels")
    missing = [name for name in REQUIRED if name not in channels]
    if missing:
        raise InputError(f"channel {missing[0]!r} is missing; expected "
                         "target=PV,reference=PV[,test=PV]", parameter="channels")
    return dict(channels)


def from_test_numbers(samples: pd.DataFrame, path) -> pd.DataFrame:
    """Approaches marked by ecmc test numbers (see the module docstring).

    Parameters
    ----------
    samples : DataFrame
        ``read_camonitor`` rows with channels ``target``, ``reference``, ``test``.

    Returns
    -------
    DataFrame
        One row per approach, in time order: ``target`` [set point units], ``direction``,
        ``cycle``, ``position`` (index), ``reference``, ``time``, ``started`` (when its test
        number was set), ``row``.
    """
    test = samples["test"].to_numpy()
    start = np.r_[True, test[1:] != test[:-1]]
    first = np.flatnonzero(start)
    last = np.r_[first[1:] - 1, len(test) - 1]  # the last sample before the number changes
    code = test[first]
    iso = (code == np.round(code)) & (code >= 1000) & (code < 3000)
    code = np.round(code).astype(np.int64)
    iso &= (code // 100 % 10 >= 1) & (code % 100 >= 1)
    other = sorted({int(c) for c in code[~iso] if c != 0})
    if other:
        note(f"{path}: test numbers {', '.join(map(str, other[:5]))}"
             f"{' ...' if len(other) > 5 else ''} are not ISO 230-2 approaches (direction "
             "digit 1 or 2, cycle digit, two-digit position); left out")
    if not iso.any():
        raise InputError("no ISO 230-2 test numbers (1101 = forward, cycle 1, position 1) in "
                         "the test channel; expected ecmc's test numbers, or no test channel "
                         "to find the stops", file=path, parameter="channels")
    rows = samples.iloc[last[iso]]
    found = pd.DataFrame({
        "code": code[iso], "target": rows["target"].to_numpy(),
        "direction": np.where(code[iso] // 1000 == 1, "+", "-"),
        "cycle": code[iso] // 100 % 10, "position": code[iso] % 100,
        "reference": rows["reference"].to_numpy(), "time": rows["time"].array,
        "started": samples["time"].iloc[first[iso]].array, ROW: rows["row"].to_numpy()})
    twice = found["code"].duplicated(keep=False)
    if twice.any():
        again = found[twice].iloc[[0, 1]]
        raise InputError(f"test number {again['code'].iloc[0]} is set twice (rows "
                         f"{again[ROW].iloc[0]} and {again[ROW].iloc[1]}); expected one ISO "
                         "230-2 run per log", file=path, row=int(again[ROW].iloc[1]))
    spread = found.groupby("position")["target"].agg(lambda t: t.max() - t.min())
    if (spread > SAME_TARGET_MM).any():
        pos = int(spread.idxmax())
        values = found.loc[found["position"] == pos, "target"]
        raise InputError(f"position {pos} has set points {values.min():g} and "
                         f"{values.max():g}; expected one target per position index",
                         file=path, parameter="channels")
    return found.drop(columns="code")


def find_stops(samples: pd.DataFrame, dwell_s: float = DWELL_S,
               tolerance: float = TOLERANCE_MM) -> pd.DataFrame:
    """Every hold of the set point of at least ``dwell_s`` [s], in time order.

    Returns
    -------
    DataFrame
        ``target`` (the set point held), ``direction`` (the side it came from: the sign of
        the hold minus the last set point before it farther than ``tolerance`` [mm], so an
        open-loop counter settling back by a step does not count), ``reference`` (logged last
        before the set point moves on), ``time`` (of that sample), ``started`` (when the hold
        began), ``row``. A hold that no set point since the previous one is farther from has
        no direction and is left out.
    """
    target = samples["target"].to_numpy()
    seconds = (samples["time"] - samples["time"].iloc[0]).dt.total_seconds().to_numpy()
    change = np.flatnonzero(np.r_[False, target[1:] != target[:-1]])
    until = np.r_[change[1:], len(target)]  # first sample of the next move (or the end)
    held = np.r_[seconds[change[1:]], seconds[-1]] - seconds[change]
    stops = change[held >= dwell_s]
    value = target[stops]
    side = np.zeros(len(stops))
    for k, (begin, end) in enumerate(zip(np.r_[0, stops[:-1]], stops)):
        far = np.flatnonzero(np.abs(target[begin:end] - value[k]) > tolerance)
        if len(far):
            side[k] = value[k] - target[begin + far[-1]]
    rows = samples.iloc[until[held >= dwell_s] - 1]
    found = pd.DataFrame({
        "target": value, "direction": np.where(side > 0, "+", "-"),
        "reference": rows["reference"].to_numpy(), "time": rows["time"].array,
        "started": samples["time"].iloc[stops].array, ROW: rows["row"].to_numpy()})
    return found[side != 0].reset_index(drop=True)


def from_stops(samples: pd.DataFrame, path, dwell_s: float = DWELL_S,
               tolerance: float = TOLERANCE_MM) -> pd.DataFrame:
    """Approaches found as settled stops of the set point (see the module docstring).

    Returns
    -------
    DataFrame
        As ``from_test_numbers`` (``position`` is the target's rank).
    """
    found = find_stops(samples, dwell_s, tolerance)
    if found.empty:
        raise InputError(f"no stop of the set point lasts {dwell_s:g} s; expected an ISO "
                         "230-2 run with dwells at its targets", file=path)
    values = np.sort(found["target"].unique())
    group = np.cumsum(np.r_[0, np.diff(values) > tolerance])
    found["position"] = group[np.searchsorted(values, found["target"])] + 1
    found["target"] = found.groupby("position")["target"].transform("mean")
    both = found.groupby("position")["direction"].transform("nunique") == 2
    if not both.all():
        left = np.unique(found.loc[~both, "target"])
        note(f"{path}: stops at {', '.join(f'{v:g}' for v in left[:5])} are reached from one "
             "direction only (overrun or parking positions); left out")
    found = found[both].copy()
    if found.empty:
        raise InputError("no target is stopped at from both directions; expected an ISO 230-2 "
                         "run", file=path)
    found["position"] = pd.factorize(found["position"], sort=True)[0] + 1
    found["cycle"] = found.groupby(["position", "direction"]).cumcount() + 1
    return found


def to_readings(found: pd.DataFrame, path, reference_map: tuple[float, float]
                ) -> pd.DataFrame:
    """Approaches -> long readings of a linear axis (not yet validated), the reference mapped
    by ``reference_map`` = (scale, offset) to mm; names are the caller's."""
    scale, offset = reference_map
    measured = scale * found["reference"].to_numpy() + offset
    direction = found["direction"].to_numpy()
    pendulum = len(direction) > 1 and bool(np.all(direction[1:] != direction[:-1]))
    return pd.DataFrame({
        "machine_id": Path(path).stem, "axis": "X", "test_id": Path(path).stem,
        "method": "pendulum" if pendulum else "linear",
        "target": found["target"].to_numpy(), "direction": direction,
        "cycle": found["cycle"].to_numpy(),
        "deviation_um": (measured - found["target"].to_numpy()) * 1000.0,
        "measured": measured, "started_at": found["started"].min(),
        "measured_at": found["time"].array, ROW: found[ROW].to_numpy()})


def _reference_map(found: pd.DataFrame, path: Path, reference_scale, factor: float = 1.0
                   ) -> tuple[float, float]:
    """(scale, offset) from reference to axis coordinates in mm (deg): given in the set
    point's unit (times ``factor``), or fitted (with a note)."""
    if reference_scale is not None:
        try:
            pair = np.atleast_1d(np.asarray(reference_scale, dtype=float))
        except (TypeError, ValueError):
            pair = np.array([])
        if not 1 <= len(pair) <= 2 or not np.isfinite(pair).all() or pair[0] == 0:
            raise InputError(f"{reference_scale!r}: expected a scale or (scale, offset), finite "
                             "numbers with a scale not 0", parameter="reference_scale")
        return float(pair[0]) * factor, (float(pair[1]) if len(pair) > 1 else 0.0) * factor
    ref, target = found["reference"].to_numpy(), found["target"].to_numpy()
    if np.ptp(ref) == 0 or np.ptp(target) == 0:
        raise InputError("the reference or the set point does not move; cannot fit a gear "
                         "ratio, expected --reference-scale", file=path,
                         parameter="reference_scale")
    scale, offset = np.polyfit(ref, target, 1)
    residual = target - (scale * ref + offset)
    note(f"{path}: reference mapped with a fitted gear ratio {scale:.6g} and offset "
         f"{offset:.10g} ({len(ref)} readings, residual {np.sqrt(np.mean(residual**2)) * 1e3:.3g}"
         " um rms); the fit takes up the linear positioning error: give --reference-scale to "
         "keep it")
    return float(scale), float(offset)


def _names(target_pv: str) -> tuple[str, str | None, str]:
    """(machine_id, axis or None when not stated, record) from the set-point PV."""
    m = _RECORD.match(target_pv)
    if m is None:
        return target_pv, None, target_pv
    record = m["record"]
    if record.upper() in schema.LINEAR_AXES + schema.ROTARY_AXES:
        return m["ioc"], record.upper(), record
    return f"{m['ioc']}:{record}", None, record
