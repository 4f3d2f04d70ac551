"""ISO 230-2 approach readings from a controller's raw log (``--format camonitor``).

An ISO 230-2 run [ISO230-2] moves the axis to each target P_i from both directions, cycle
after cycle, and reads the reference (a laser, a linear scale) once the axis has settled. A
raw log holds that run as time series: the set point (``target`` channel), the reference
(``reference``), optionally the motor side (``motor``: an open-loop step counter or the motor
encoder) and, in ecmc's test scripts, a test number (``test``). This module finds the
approaches in the log and makes them readings. The rules are ecmc's own extraction
(``ecmcGetISO230DataFromCAFile.bash`` with ``ecmcGetDataBeforeTrigg.bash``, called by
``mainISO230_2.bash``, in ecmc's public ``ecmccomgui`` tools):

- **with test numbers** (``from_test_numbers``): ecmc sets the test-number PV once the axis
  has settled at the target of an approach. The number is the text ``d c 0 p``: direction
  digit d (1 forward = ``+``, 2 backward = ``-``), the cycle c and the position index p, each
  zero-padded to the width of the largest (``seq -w``): 1101 is forward, cycle 1, position 1;
  with ten positions 11001 .. 11010. The reading of approach N is the reference value logged
  last before the line where the test number takes N, in the file's order (ecmc greps the
  lines, it does not sort them by time); its target is the set point logged last before that
  line. Other numbers (0, ecmc's limit-switch and resolver tests) are not approaches.
- **without them** (``from_stops``): a stop is a set point held for at least ``dwell_s``
  during which the axis settles: the reference (and the motor side, when mapped) stays
  within a band for ``SETTLE_S`` (the band is eight times the reference's own sample noise,
  at least ``SETTLE_FLOOR_UM``). The reading is the last sample of the first settled window
  of the hold, so motion after it (ecmc's resolver test moves the axis after the run while
  the set point still holds the last target) is never read. A hold that never settles is
  refused: a reading taken while the axis moves is no measurement. The direction of a stop is
  the side it came from (the last set point farther than ``tolerance``). Stops are grouped
  into targets (set points within ``tolerance`` of each other); only targets stopped at from
  both directions are ISO targets (an overrun or parking position is reached one way only),
  the cycle is the count of stops at a target and direction so far, and every target and
  direction must have as many stops: an extra stop outside the run is refused, not guessed.

The reference is mapped to axis coordinates (``to_readings``): ``measured = scale * reference
+ offset`` [in the set point's unit] with ``reference_scale = (scale, offset)``, as ecmc's
``REF_GR``/``REF_OFF`` (negative ratios included); without it the gear ratio and offset are
fitted to the set points by least squares, as ecmc's own report does, and reported in a note.
A fitted ratio takes up the reference's scale and zero, and with them the axis's linear
positioning error and mean deviation: reversal values and repeatability keep (up to the
ratio), E and M lose their linear part. Give the scale when it is known.

The axis is named from the set-point PV ``IOC:RECORD-...`` (ecmc's ``IOC_TEST:Axis1-PosSet``
or ``-PosCmd``): a record named X, Y, Z, A, B or C is that axis of machine ``IOC``; any other
record (``Axis1``, ``M1``) is machine ``IOC:RECORD``, axis X, marked as not stated so that
``--axis`` names it (``docs/input-formats.md``). The set point is in mm unless ``unit`` says
``um`` or ``deg`` (a rotary axis: A, or the axis the PV names); an axis A, B or C is in deg.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.camonitor import (
    check_time_order,
    parse_camonitor,
    parse_channels,
    read_camonitor,
    valid_values,
)
from features.readings.errors import InputError, note
from features.readings.validation import ROW

# Channels an ISO 230-2 run's log maps; ``test`` and ``motor`` are optional.
CHANNELS = ("target", "reference", "test", "motor")
REQUIRED = ("target", "reference")
# Default minimum hold of the set point that makes a stop [s] (ISO 230-2 dwells are seconds).
DWELL_S = 1.0
# Stops whose set points are this close are one target [mm].
TOLERANCE_MM = 0.005
# Set points of one position index may differ by this much [mm] (float round-off).
SAME_TARGET_MM = 1e-6
# A settled axis stays within its band for this long [s] ...
SETTLE_S = 0.5
# ... a band of this many times the sample noise of the signal, and at least this wide [um]:
# a creep of 2 um/s is settled for a positioning test, a move of 5 mm/s is 50 um per sample.
SETTLE_NOISE = 8.0
SETTLE_FLOOR_UM = 1.0
# Units the set point may be logged in: factor to the readings' mm (deg), rotary or not.
UNITS = {"mm": (1.0, False), "um": (1e-3, False), "deg": (1.0, True)}
# The set-point PV of an ecmc axis: ``IOC:Axis1-PosSet`` (or the commanded ``-PosCmd``).
SET_POINT_SUFFIXES = ("-PosSet", "-PosCmd")
_RECORD = re.compile(r"^(?P<ioc>[^:]+):(?P<record>[^-:.]+)[-:.]")


def read_camonitor_readings(path, channels=None, reference_scale=None, unit: str | None = None,
                            dwell_s: float = DWELL_S, tz: str = "UTC") -> pd.DataFrame:
    """The ``camonitor`` layout: the approach readings of an ISO 230-2 run in a raw log.

    Parameters
    ----------
    path : str or path-like
        The camonitor log.
    channels : dict or str, optional
        ``{"target": PV, "reference": PV, "test": PV, "motor": PV}`` or
        ``"target=PV,reference=PV,..."`` (``test`` and ``motor`` optional). None: the PV
        ending ``TestNumber`` is ``test``, the one ending ``-PosSet`` (``-PosCmd``) is
        ``target``, ``-PosAct`` of the same record is ``motor`` and the only other PV is
        ``reference``.
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
    given = _given_scale(reference_scale, factor)
    if "test" in channels:
        found = from_test_numbers(lines, channels, path)
        found["target"] *= factor  # to mm (deg)
    else:
        samples = read_camonitor(path, channels, tz, lines=lines)
        for side in {"target", "motor"} & set(samples):
            samples[side] *= factor  # to mm (deg): the tolerances are in mm
        found = from_stops(samples, path, dwell_s, scale=given and given[0])
    mapping = given if given is not None else _fitted_scale(found, path)
    readings = to_readings(found, path, mapping)
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
        channels = _inferred_channels(list(dict.fromkeys(lines["pv"])), path)
    unknown = [name for name in channels if name not in CHANNELS]
    if unknown:
        raise InputError(f"unknown channel {unknown[0]!r}; expected target, reference and "
                         "optionally test and motor", parameter="channels")
    missing = [name for name in REQUIRED if name not in channels]
    if missing:
        raise InputError(f"channel {missing[0]!r} is missing; expected "
                         "target=PV,reference=PV[,test=PV][,motor=PV]", parameter="channels")
    return dict(channels)


def _inferred_channels(pvs: list[str], path: Path) -> dict[str, str]:
    """ecmc's names: ``...TestNumber``, the axis's ``-PosSet``/``-PosCmd`` and ``-PosAct``,
    and one other PV, the reference."""
    test = [pv for pv in pvs if pv.endswith("TestNumber")]
    target = [pv for pv in pvs if pv.endswith(SET_POINT_SUFFIXES)]
    motor = [pv for pv in pvs if len(target) == 1
             and pv == target[0].rsplit("-", 1)[0] + "-PosAct"]
    rest = [pv for pv in pvs if pv not in test + target + motor]
    if len(test) > 1 or len(target) != 1 or len(rest) != 1:
        raise InputError(f"cannot tell which PV is which among {', '.join(pvs)}; expected "
                         "--channels target=PV,reference=PV[,test=PV][,motor=PV]", file=path,
                         parameter="channels")
    return {"target": target[0], "reference": rest[0],
            **({"test": test[0]} if test else {}), **({"motor": motor[0]} if motor else {})}


# ------------------------------------------------------------------ with test numbers


def from_test_numbers(lines: pd.DataFrame, channels: dict[str, str], path) -> pd.DataFrame:
    """Approaches marked by ecmc's test numbers (see the module docstring).

    Parameters
    ----------
    lines : DataFrame
        ``parse_camonitor`` rows, in file order.
    channels : dict
        ``target``, ``reference`` and ``test`` PVs.

    Returns
    -------
    DataFrame
        One row per approach, in file order: ``target`` [set point units], ``direction``,
        ``cycle``, ``position`` (index), ``reference``, ``time`` (of the reference line),
        ``started`` (when its test number was set), ``row`` (the reference line).
    """
    names = {channels[c]: c for c in ("target", "reference", "test")}
    _check_logged(lines, names, path)
    mine = valid_values(lines[lines["pv"].isin(list(names))], path, names)
    check_time_order(mine, path)
    pv, value = mine["pv"].to_numpy(), mine["value"].to_numpy()
    index = np.arange(len(mine))
    # the last line of a PV before each line: a forward fill of its line numbers, shifted
    last = {c: _last_before(np.where(pv == channels[c], index, -1)) for c in ("target",
                                                                              "reference")}
    is_test = pv == channels["test"]
    tests = np.flatnonzero(is_test)
    code = value[tests]
    if not np.isfinite(code).all():
        bad = mine.iloc[tests[~np.isfinite(code)][0]]
        raise InputError(f"test number {bad['text']!r} is not a number", file=path,
                         row=int(bad["row"]))
    changed = np.r_[True, code[1:] != code[:-1]]  # where the number takes a new value
    tests, code = tests[changed], code[changed]
    decoded = decode_test_numbers(code, path)
    tests, decoded = tests[decoded["iso"]], decoded[decoded["iso"]]
    ref_line, target_line = last["reference"][tests], last["target"][tests]
    if (ref_line < 0).any() or (target_line < 0).any():
        first = mine.iloc[tests[(ref_line < 0) | (target_line < 0)][0]]
        raise InputError(f"test number {first['text']} is set before the set point and the "
                         "reference are logged; expected the reading logged before its test "
                         "number (ecmc sets the number once the axis has settled)", file=path,
                         row=int(first["row"]))
    refs = mine.iloc[ref_line]
    found = pd.DataFrame({
        "code": decoded["code"].to_numpy(), "target": value[target_line],
        "direction": decoded["direction"].to_numpy(), "cycle": decoded["cycle"].to_numpy(),
        "position": decoded["position"].to_numpy(), "reference": value[ref_line],
        "time": refs["time"].array, "started": mine["time"].iloc[tests].array,
        ROW: refs["row"].to_numpy()})
    _check_once(found, mine.iloc[tests], path)
    _check_one_target(found, path)
    return found.drop(columns="code").reset_index(drop=True)


def _last_before(marked: np.ndarray) -> np.ndarray:
    """For each position k, the largest marked index < k (-1 where none): ``marked`` holds an
    index where the line is of the wanted PV, else -1."""
    upto = np.maximum.accumulate(marked)
    return np.r_[-1, upto[:-1]]


def decode_test_numbers(code: np.ndarray, path) -> pd.DataFrame:
    """ecmc's test numbers ``d c 0 p`` (cycle and position zero-padded to the width of the
    largest, ``seq -w``) -> ``code``, ``iso``, ``direction``, ``cycle``, ``position``.

    The widths are those that read every candidate number (direction 1 or 2) with the
    separator 0 and make the largest cycle and position as wide as their field. A number
    that fits no run's widths is not an approach (a note names it).
    """
    whole = (code == np.round(code)) & (code > 0)
    text = np.array([f"{int(c)}" if ok else "" for c, ok in zip(code, whole)])
    candidate = np.array([len(t) >= 4 and t[0] in "12" for t in text])
    widths = _widths(text[candidate])
    iso = np.zeros(len(code), bool)
    cycle, position = np.zeros(len(code), int), np.zeros(len(code), int)
    if widths is not None:
        wc, wp = widths
        for k in np.flatnonzero(candidate):
            t = text[k]
            if len(t) == 2 + wc + wp and t[1 + wc] == "0":
                c, p = int(t[1:1 + wc]), int(t[2 + wc:])
                if c >= 1 and p >= 1:
                    iso[k], cycle[k], position[k] = True, c, p
    other = sorted({t or f"{c:g}" for t, c, ok in zip(text, code, iso) if not ok and c != 0})
    if other:
        note(f"{path}: test numbers {', '.join(other[:5])}{' ...' if len(other) > 5 else ''} "
             "are not ISO 230-2 approaches (direction digit 1 or 2, cycle, 0, position); left "
             "out")
    if not iso.any():
        raise InputError("no ISO 230-2 test numbers (1101 = forward, cycle 1, position 1) in "
                         "the test channel; expected ecmc's test numbers, or no test channel "
                         "to find the stops", file=path, parameter="channels")
    first = np.array([int(t[0]) if t else 0 for t in text])
    return pd.DataFrame({"code": [int(c) if ok else 0 for c, ok in zip(code, iso)],
                         "iso": iso, "direction": np.where(first == 1, "+", "-"),
                         "cycle": cycle, "position": position})


def _widths(texts: np.ndarray) -> tuple[int, int] | None:
    """(cycle width, position width) of ecmc's numbers among ``texts``: the split that reads
    the most of them, each field as wide as its largest value (``seq -w``)."""
    best, most = None, 0
    for length in sorted({len(t) for t in texts}):
        for wc in range(1, length - 2):
            wp = length - 2 - wc
            fit = [t for t in texts if len(t) == length and t[1 + wc] == "0"
                   and int(t[1:1 + wc]) >= 1 and int(t[2 + wc:]) >= 1]
            if not fit:
                continue
            c_max = max(int(t[1:1 + wc]) for t in fit)
            p_max = max(int(t[2 + wc:]) for t in fit)
            if len(str(c_max)) == wc and len(str(p_max)) == wp and len(fit) > most:
                best, most = (wc, wp), len(fit)
    return best


def _check_logged(lines: pd.DataFrame, names: dict[str, str], path: Path) -> None:
    logged = set(lines["pv"].unique())
    for pv, name in names.items():
        if pv not in logged:
            raise InputError(f"PV {pv!r} (channel {name}) is never logged; the file logs "
                             f"{', '.join(sorted(logged))}", file=path)
    if len(names) != 3:
        raise InputError("two channels name the same PV; expected one PV per channel",
                         file=path, parameter="channels")
    mine = lines[lines["pv"].isin(list(names))]
    bad = ~np.isfinite(mine["value"].to_numpy()) & (mine["severity"].to_numpy() != "INVALID")
    if bad.any():
        first = mine.iloc[int(np.flatnonzero(bad)[0])]
        raise InputError(f"PV {first['pv']} (channel {names[first['pv']]}) logs "
                         f"{first['text']!r}; expected a finite number", file=path,
                         row=int(first["row"]))


def _check_once(found: pd.DataFrame, test_lines: pd.DataFrame, path: Path) -> None:
    twice = found["code"].duplicated(keep=False).to_numpy()
    if twice.any():
        rows = test_lines["row"].to_numpy()[twice][:2]
        raise InputError(f"test number {found['code'][twice].iloc[0]} is set twice (rows "
                         f"{rows[0]} and {rows[1]}); expected one ISO 230-2 run per log",
                         file=path, row=int(rows[1]))


def _check_one_target(found: pd.DataFrame, path: Path) -> None:
    spread = found.groupby("position")["target"].agg(lambda t: t.max() - t.min())
    if (spread > SAME_TARGET_MM).any():
        pos = int(spread.idxmax())
        values = found.loc[found["position"] == pos, "target"]
        raise InputError(f"position {pos} has set points {values.min():g} and "
                         f"{values.max():g}; expected one target per position index (the set "
                         "point logged last before its test number)", file=path,
                         parameter="channels")


# ------------------------------------------------------------------ without test numbers


def find_stops(samples: pd.DataFrame, dwell_s: float = DWELL_S,
               tolerance: float = TOLERANCE_MM, scale: float | None = None,
               path=None) -> pd.DataFrame:
    """Every hold of the set point of at least ``dwell_s`` [s] where the axis settles, in
    time order.

    Parameters
    ----------
    samples : DataFrame
        ``read_camonitor`` rows with channels ``target`` and ``reference`` (``motor``
        optional), the set point in mm (deg).
    dwell_s : float
        Minimum hold of the set point [s].
    tolerance : float
        Set points this close [mm] are one.
    scale : float, optional
        mm of axis travel per unit of the reference; None: estimated from the holds.
    path : path-like, optional
        The log, for errors.

    Returns
    -------
    DataFrame
        ``target`` (the set point held), ``direction`` (the side it came from: the sign of
        the hold minus the last set point before it farther than ``tolerance``, so an
        open-loop counter settling back by a step does not count), ``reference`` (the last
        sample of the first settled window of the hold), ``time`` (of that sample),
        ``started`` (when the hold began), ``row``. A hold that no set point since the
        previous one is farther from has no direction and is left out.

    Raises
    ------
    InputError
        A hold of ``dwell_s`` during which the axis never settles.
    """
    target = samples["target"].to_numpy()
    seconds = (samples["time"] - samples["time"].iloc[0]).dt.total_seconds().to_numpy()
    change = np.flatnonzero(np.r_[False, target[1:] != target[:-1]])
    until = np.r_[change[1:], len(target)]  # first sample of the next move (or the end)
    ends = np.r_[seconds[change[1:]], seconds[-1]]  # when each hold ends [s]
    long = ends - seconds[change] >= dwell_s
    begin, end, ends = change[long], until[long], ends[long]
    if scale is None:
        scale = _rough_scale(samples["reference"].to_numpy()[end - 1], target[begin])
    signals = {"reference": samples["reference"].to_numpy() * abs(scale) * 1e3}  # um
    if "motor" in samples:
        signals["motor"] = samples["motor"].to_numpy() * 1e3
    settled = np.ones(len(target), bool)
    for values in signals.values():
        settled &= _settled(seconds, values, begin, end, ends,
                            _band_um(values, begin, end))
    reading = np.empty(len(begin), int)
    for k, (b, e) in enumerate(zip(begin, end)):
        inside = np.flatnonzero(settled[b:e])
        if not len(inside):
            _never_settles(samples, b, e, signals, path)
        gaps = np.flatnonzero(np.diff(inside) > 1)  # the first settled window ends here
        reading[k] = b + inside[gaps[0] if len(gaps) else -1]
    value = target[begin]
    side = np.zeros(len(begin))
    for k, (b, e) in enumerate(zip(np.r_[0, begin[:-1]], begin)):
        far = np.flatnonzero(np.abs(target[b:e] - value[k]) > tolerance)
        if len(far):
            side[k] = value[k] - target[b + far[-1]]
    rows = samples.iloc[reading]
    found = pd.DataFrame({
        "target": value, "direction": np.where(side > 0, "+", "-"),
        "reference": rows["reference"].to_numpy(), "time": rows["time"].array,
        "started": samples["time"].iloc[begin].array, ROW: rows["row"].to_numpy()})
    return found[side != 0].reset_index(drop=True)


def _rough_scale(reference: np.ndarray, target: np.ndarray) -> float:
    """mm per reference unit from the ends of the holds (for the settling band only)."""
    if len(reference) < 2 or np.ptp(reference) == 0 or np.ptp(target) == 0:
        return 1.0
    return float(np.polyfit(reference, target, 1)[0])


def _band_um(values: np.ndarray, begin: np.ndarray, end: np.ndarray) -> float:
    """The settling band of a signal [um]: ``SETTLE_NOISE`` times its sample noise (robust
    standard deviation of the steps between samples during the holds, where most of them
    are at rest), at least ``SETTLE_FLOOR_UM``."""
    steps = np.concatenate([np.diff(values[b:e]) for b, e in zip(begin, end)] or [[]])
    steps = steps[steps != 0]  # a sample of another channel repeats the value
    noise = 1.4826 * np.median(np.abs(steps)) / np.sqrt(2) if len(steps) else 0.0
    return max(SETTLE_FLOOR_UM, SETTLE_NOISE * noise)


def _settled(seconds, values, begin, end, ends, band: float) -> np.ndarray:
    """Per sample: the signal has stayed within ``band`` over the last ``SETTLE_S`` of its
    hold (a hold younger than that is not settled yet). camonitor logs a value only when it
    changes, so a signal at rest may log nothing: the last sample of a hold is also settled
    when nothing beyond the band was logged in the ``SETTLE_S`` before the hold ends."""
    out = np.zeros(len(values), bool)
    for b, e, t_end in zip(begin, end, ends):
        t, v = seconds[b:e], values[b:e]
        frame = pd.Series(v, index=pd.to_timedelta(t, unit="s"))
        window = frame.rolling(pd.Timedelta(seconds=SETTLE_S), closed="both")
        spread = (window.max() - window.min()).to_numpy()
        out[b:e] = (t - t[0] >= SETTLE_S) & (spread <= band)
        since = max(int(np.searchsorted(t, t_end - SETTLE_S, side="right")) - 1, 0)
        if t_end - t[0] >= SETTLE_S and np.ptp(v[since:]) <= band:
            out[e - 1] = True
    return out


def _never_settles(samples, b: int, e: int, signals: dict, path) -> None:
    moved = {name: float(np.ptp(v[b:e])) for name, v in signals.items()}
    name = max(moved, key=moved.get)
    first = samples.iloc[b]
    raise InputError(f"the set point holds {samples['target'].iloc[b]:g} from "
                     f"{first['time']:%H:%M:%S.%f} for "
                     f"{(samples['time'].iloc[e - 1] - first['time']).total_seconds():.3g} s "
                     f"but the {name} never settles (moves {moved[name]:.3g} um); a reading "
                     "taken while the axis moves is no measurement: expected the axis at "
                     "rest at each stop, or the test channel (test=PV) to mark the readings",
                     file=path, row=int(first["row"]))


def from_stops(samples: pd.DataFrame, path, dwell_s: float = DWELL_S,
               tolerance: float = TOLERANCE_MM, scale: float | None = None) -> pd.DataFrame:
    """Approaches found as settled stops of the set point (see the module docstring).

    Returns
    -------
    DataFrame
        As ``from_test_numbers`` (``position`` is the target's rank).
    """
    found = find_stops(samples, dwell_s, tolerance, scale, path)
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
    _check_cycles(found, path)
    return found


def _check_cycles(found: pd.DataFrame, path) -> None:
    """Every target and direction stopped at as often: a stop too many lies outside the run
    (a test before or after it), and which one cannot be told without test numbers."""
    counts = found.groupby(["target", "direction"]).size()
    if counts.nunique() > 1:
        usual = int(counts.mode().iloc[0])
        (at, way), n = next((key, n) for key, n in counts.items() if n != usual)
        raise InputError(f"target {at:g} is stopped at {n} times from {way} but the others "
                         f"{usual} times; expected every target and direction in each cycle "
                         "(a stop outside the run?): give the test channel (test=PV)",
                         file=path, parameter="channels")


# ------------------------------------------------------------------ to readings


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


def _given_scale(reference_scale, factor: float = 1.0) -> tuple[float, float] | None:
    """(scale, offset) from reference to axis coordinates in mm (deg), given in the set
    point's unit (times ``factor``); None when not given."""
    if reference_scale is None:
        return None
    try:
        pair = np.atleast_1d(np.asarray(reference_scale, dtype=float))
    except (TypeError, ValueError):
        pair = np.array([])
    if not 1 <= len(pair) <= 2 or not np.isfinite(pair).all() or pair[0] == 0:
        raise InputError(f"{reference_scale!r}: expected a scale or (scale, offset), finite "
                         "numbers with a scale not 0", parameter="reference_scale")
    return float(pair[0]) * factor, (float(pair[1]) if len(pair) > 1 else 0.0) * factor


def _fitted_scale(found: pd.DataFrame, path: Path) -> tuple[float, float]:
    """(scale, offset) fitted to the set points by least squares, with a note."""
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
