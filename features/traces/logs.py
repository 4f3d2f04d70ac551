"""Traces from a controller's raw log: an EPICS ``camonitor`` log or a LinuxCNC
``halsampler``/``halscope`` export, read into the trace contract (``features.traces.contract``).

The raw readers (``features.readings.camonitor.read_camonitor``,
``features.readings.halsampler.read_halsampler``) give ``time`` and one column per channel;
``channels`` maps the trace's channel names (``commanded``, ``motor``, ``load`` and the
optional ``motor_current``, ``following_error``, ``machine_temp``) to a log's PVs (camonitor)
or fields/pins (halsampler; ``sample`` marks a ``halsampler -t`` sample number), e.g. ``{"commanded": "MC:X-PosSet", "motor": "MC:X-PosAct",
"load": "MC:ec0-s4-EL5101-Enc-PosAct"}``. Values are taken as logged, in the contract's units
(mm or deg), except the load side's with a ``reference_scale`` (gain, offset): load position =
gain * logged value + offset, in the commanded channel's unit (a resolver logged in counts, an
external reference counting the other way or with its own zero). The machine and axis come from the commanded (set-point) PV's name
when it states them (its IOC prefix; ``features.readings.formats.axis_from_pv`` for the axis),
else from ``machine``/``axis``, which also override the name.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from features.readings.errors import InputError
from features.readings.schema import LINEAR_AXES, ROTARY_AXES
from features.traces import contract as c
from features.traces.validation import check_trace

LOG_FORMATS = ("camonitor", "halsampler")
# Channel name -> trace column: the contract's channels without their unit suffix.
COLUMNS = {name.rsplit("_", 1)[0]: name for name in c.CHANNELS}
REQUIRED = ("commanded", "motor")
AXES = (*LINEAR_AXES, *ROTARY_AXES)


def read_log_trace(path, format: str, channels, machine: str | None = None,
                   axis: str | None = None, period_s: float | None = None,
                   start=None, reference_scale=None) -> pd.DataFrame:
    """A raw controller log as a validated trace frame (one machine axis).

    Parameters
    ----------
    path : str or path-like
        The log.
    format : {'camonitor', 'halsampler'}
        Its layout.
    channels : dict or str
        Trace channel -> PV (camonitor) or 0-based field number / pin name (halsampler), or
        ``"commanded=PV,motor=PV,load=PV"``. ``commanded`` and ``motor`` are required.
    machine, axis : str, optional
        The machine and axis; default what the commanded PV's name states.
    period_s : float, optional
        Sample period [s] of halsampler output (``read_halsampler``).
    start : datetime or str, optional
        Time of a halsampler file's first sample (``read_halsampler``).
    reference_scale : float or (float, float), optional
        The load side's gain, or (gain, offset): load = gain * logged + offset.

    Returns
    -------
    DataFrame
        A trace as ``features.traces.io.read_trace`` returns it.

    Raises
    ------
    InputError
        An unknown format or channel, a required channel missing, a PV or field the log does
        not have, a machine or axis neither named nor given, a reference scale that is no
        (gain, offset) of finite numbers with a gain not 0.
    """
    path = Path(path)
    gain, offset = _scale(reference_scale)
    if format not in LOG_FORMATS:
        raise InputError(f"unknown log format {format!r}; expected {' or '.join(LOG_FORMATS)}",
                         parameter="format")
    channels = _channels(channels, format)
    if format == "camonitor":
        from features.readings.camonitor import read_camonitor

        # one PV may feed two channels (a stepper's step counter as commanded and motor)
        first = {}
        for name, pv in channels.items():
            first.setdefault(pv, name)
        logged = _instants(read_camonitor(path, {name: pv for pv, name in first.items()}))
        samples = pd.DataFrame({"time": logged["time"],
                                **{n: logged[first[pv]] for n, pv in channels.items()}})
        named_machine, named_axis = _names(channels["commanded"])
    else:
        from features.readings.halsampler import read_halsampler

        samples = read_halsampler(path, channels, period_s=period_s, start=start)
        named_machine = named_axis = None
    machine = machine or named_machine
    axis = axis or named_axis
    if axis and axis.upper() not in AXES:  # refused here: a frame row would name no file line
        raise InputError(f"unknown axis {axis!r}; expected one of {', '.join(AXES)}",
                         parameter="axis")
    for what, value in (("machine", machine), ("axis", axis)):
        if not value:
            raise InputError(f"the log's channel names state no {what}; expected --{what} "
                             f"(Python {what}=)", file=path, parameter=what)
    frame = pd.DataFrame({"time": samples["time"], "machine_id": machine, "axis": axis})
    for name in channels.keys() & COLUMNS.keys():
        frame[COLUMNS[name]] = samples[name].to_numpy(dtype=float)
    if "load_mm" in frame:
        frame["load_mm"] = gain * frame["load_mm"] + offset
    return check_trace(frame, path)


def _scale(reference_scale) -> tuple[float, float]:
    """(gain, offset) of the load side; (1, 0) when not given."""
    if reference_scale is None:
        return 1.0, 0.0
    pair = np.atleast_1d(np.asarray(reference_scale, dtype=object))
    try:
        numbers = [float(v) for v in pair]
    except (TypeError, ValueError):
        numbers = []
    if not 1 <= len(numbers) <= 2 or not np.isfinite(numbers).all() or numbers[0] == 0:
        raise InputError(f"{reference_scale!r}: expected GAIN or (GAIN, OFFSET), finite "
                         "numbers with a gain not 0", parameter="reference_scale")
    return numbers[0], numbers[1] if len(numbers) > 1 else 0.0


def _instants(logged: pd.DataFrame) -> pd.DataFrame:
    """One row per logged time: camonitor writes a line per PV update, so PVs updated in one
    controller cycle share a time, and only the last of those lines holds every PV's value
    at that time (the ones before still hold older values)."""
    last = ~logged["time"].duplicated(keep="last").to_numpy()
    return logged if last.all() else logged[last].reset_index(drop=True)


def _channels(channels, format: str) -> dict:
    """A checked mapping; halsampler field numbers given as text become ints."""
    if isinstance(channels, str):
        channels = parse_log_channels(channels)
    if not channels:
        raise InputError("no channels; expected commanded=PV,motor=PV,load=PV",
                         parameter="channels")
    known = (*COLUMNS, "sample") if format == "halsampler" else tuple(COLUMNS)
    unknown = [name for name in channels if name not in known]
    if unknown:
        raise InputError(f"unknown channel {unknown[0]!r}; expected "
                         f"{', '.join(COLUMNS)}", parameter="channels")
    missing = [name for name in REQUIRED if name not in channels]
    if missing:
        raise InputError(f"channel {missing[0]!r} is missing; expected "
                         "commanded=PV,motor=PV,load=PV", parameter="channels")
    if format == "halsampler":
        return {n: int(k) if str(k).isdigit() else k for n, k in channels.items()}
    return dict(channels)


def parse_log_channels(text: str) -> dict:
    """``"commanded=PV,motor=PV,load=PV"`` -> the mapping, its messages in this module's
    channel names (``parse_channels``, shared with convert, names convert's)."""
    from features.readings.camonitor import parse_channels

    expected = "expected name=PV pairs separated by commas: commanded=PV,motor=PV,load=PV"
    for entry in filter(None, (e.strip() for e in str(text).split(","))):
        name, sep, pv = (part.strip() for part in entry.partition("="))
        if ";" in entry or not sep or not name or not pv or any(c.isspace() for c in pv):
            raise InputError(f"{entry!r} is not name=PV; {expected}", parameter="channels")
    if not str(text).strip(", "):
        raise InputError(f"no channels; {expected}", parameter="channels")
    return parse_channels(text)


def _names(pv: str) -> tuple[str | None, str | None]:
    """(machine, axis) an ecmc PV's name states: its IOC prefix and the axis letter of its
    record (``axis_from_pv``); None for what it does not state."""
    from features.readings.formats import axis_from_pv

    ioc = pv.split(":", 1)[0] if ":" in pv else None
    return ioc, axis_from_pv(pv)
