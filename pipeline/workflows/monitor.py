"""Monitor: lost motion per machine axis and day from controller traces with dual feedback.

>>> import backlash as bl
>>> result = bl.monitor("traces/")                       # doctest: +SKIP
>>> result.daily[["axis", "date", "lost_motion_um"]]     # doctest: +SKIP

Each trace (docs/data-contract.md section 10: a CSV or Parquet table, or a Parquet dataset
partitioned by machine, axis and date) is cut into partitions, one machine axis's day each
(``models.condition.lost_motion.daily_lost_motion``, a pure function of its partition); they run on the
chosen engine (``pipeline.engines``: in-process by default, or Dask) and give the same numbers
wherever they run. The daily series of each axis then gets the drift statistics of laser
visits (``models.condition.drift.analyse_series``): change points (an adjustment, a failure), the trend
since the last one, alerts.

Before anything is recorded, every day is checked against what can be physical
(``models.condition.lost_motion.check_physical``): a load side that moves against the motor side, or
travels more than twice or less than half as far (raw counts, a wrong unit or gear ratio), a
lost motion larger than the day's travel or negative beyond its uncertainty are refused.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path

from features.readings.errors import InputError, note
from pipeline.engines import ENGINES
from pipeline.results import Result, axis_alerts
from pipeline.steps.constraints import Interval, StrOptions
from pipeline.steps.parameters import PROGRESS, Param, python_only, scale_offset

_RAW = "raw controller logs (--log-format camonitor or halsampler)"
_POSITIVE = Interval(Real, 0, None, closed="neither")
# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{trace}"],
    {"traces": "{trace}"},
)

PARAMETERS = {
    "traces": Param((str, os.PathLike, list, tuple, "pandas.DataFrame"), flag="TRACE",
                    nargs="+"),
    "out": Param((str, os.PathLike, None), "output folder: monitor.json, daily.csv, "
                 "monitor.html", output="folder"),
    "engine": Param((StrOptions(ENGINES),)),
    "address": Param((str, None), metavar="URL"),
    "threshold_um": Param((_POSITIVE, None), metavar="X"),
    "take_up_mm": Param((_POSITIVE,), metavar="X"),
    "settle_s": python_only(Interval(Real, 0, None, closed="left")),
    "store": Param((str, os.PathLike, None), "fleet store (folder or postgresql:// URL; "
                   "docs/fleet.md) to record the daily lost motion in: one trace record per "
                   "machine axis and day with a value; the same days again add nothing",
                   metavar="STORE"),
    "format": Param((StrOptions(("trace", "camonitor", "halsampler")),), flag="--log-format",
                    group=_RAW),
    "channels": Param((str, dict, None), metavar="MAP", group=_RAW),
    "reference_scale": Param((Real, tuple, list, None), metavar="GAIN[,OFFSET]",
                             parse=scale_offset, group=_RAW),
    "machine": Param((str, None), group=_RAW),
    "axis": Param((str, None), group=_RAW),
    "period_s": Param((_POSITIVE, None), metavar="S", group=_RAW),
    "progress": PROGRESS,
}


LOAD_NEEDED = "lost motion needs a load-side position (column load_mm)"


@dataclass
class AxisMonitor:
    """One machine axis's daily lost motion and its drift analysis."""

    machine_id: str
    axis: str
    unit: str
    days: object  # DataFrame: the axis's rows of MonitorResult.daily
    change_points: list = field(default_factory=list)  # ISO dates: first day after a change
    slope_um_per_day: float | None = None
    alerts: list = field(default_factory=list)
    series: object = None  # models.condition.drift.DriftSeries, or None below two days

    def to_dict(self) -> dict:
        days = [{"date": r.date, "lost_motion_um": _num(r.lost_motion_um),
                 "lost_motion_u_um": _num(r.lost_motion_u_um), "reversals": int(r.reversals)}
                for r in self.days.itertuples()]
        return {"machine_id": self.machine_id, "axis": self.axis, "unit": self.unit,
                "days": days, "change_points": self.change_points,
                "slope_um_per_day": self.slope_um_per_day, "alerts": self.alerts}


def _num(value: float) -> float | None:
    return None if math.isnan(value) else round(float(value), 4)


@dataclass
class MonitorResult(Result):
    """Lost motion per machine axis and day.

    Attributes
    ----------
    daily : DataFrame
        One row per machine axis and day (``models.condition.lost_motion.DAILY_COLUMNS``):
        ``lost_motion_um`` and its standard uncertainty ``lost_motion_u_um`` (um, arcsec on a
        rotary axis), ``reversals``, ``samples``, ``lag_s``, ``control_points``. What a fleet
        store records per axis and day.
    axes : list of AxisMonitor
        Per machine axis: its days, change points, slope [um/day] and alerts.
    source : str
        The traces as given.
    engine : str
        Where the partitions ran.
    recorded : pipeline.store.records.Recorded or None
        What ``store`` recorded (the runner sets it).
    """

    daily: object
    axes: list
    source: str = ""
    engine: str = "local"
    parameters: dict = field(default_factory=dict)
    recorded: object = None

    @property
    def alerts(self) -> list[dict]:
        return axis_alerts(self.axes)

    def to_dict(self) -> dict:
        return {"axes": [a.to_dict() for a in self.axes], "notes": list(self.notes)}

    def write(self, out) -> dict[str, Path]:
        """``monitor.json``, ``daily.csv`` and the report page ``monitor.html`` (with its
        chart ``monitor.png``) under ``out``."""
        from features.readings.fileio import atomic_path, write_json
        from pipeline.reports.monitor_report import write_monitor_report

        out = Path(out)
        files = {"json": write_json(out / "monitor.json", self.to_dict())}
        with atomic_path(out / "daily.csv") as tmp:
            self.daily.to_csv(tmp, index=False)
        files["daily"] = out / "daily.csv"
        files.update(write_monitor_report(self, out))
        self.files = files
        return files


def monitor(traces, *, engine: str = "local", address: str | None = None,
            threshold_um: float | None = None, take_up_mm: float = 0.05,
            settle_s: float = 0.1, progress=None, format: str = "trace",
            channels=None, reference_scale=None, machine: str | None = None,
            axis: str | None = None, period_s: float | None = None) -> MonitorResult:
    """Lost motion per machine axis and day from dual-feedback traces, with change points.

    Parameters
    ----------
    traces : str, path, list of them, or DataFrame
        Trace tables (CSV, Parquet) and/or Parquet dataset folders partitioned by machine,
        axis and date (``machine_id=``, ``axis=``, ``date=``; docs/data-contract.md section
        10). Each needs ``load_mm``.
    engine : {'local', 'dask'}
        Where the partitions run: ``local`` (this process) or ``dask``
        (``pipeline.engines``).
    address : str, optional
        A Dask scheduler's address (``tcp://host:8786``), refused if it does not answer within
        ``pipeline.engines.SCHEDULER_TIMEOUT_S`` (10 s); default Dask's local scheduler.
    threshold_um : float, optional
        Lost-motion limit [um]: alert at or above it, forecast its crossing.
    take_up_mm : float
        Travel after a reversal past which the play is taken up [mm or deg]; larger than
        any lost motion.
    settle_s : float
        Time after an acceleration before a sample counts as steady [s].
    progress : callable, optional
        ``progress(done, total, what)`` per partition (local engine).
    format : {'trace', 'camonitor', 'halsampler'}
        What the traces are: ``trace``, trace tables and datasets; ``camonitor`` (an EPICS
        camonitor log) or ``halsampler`` (LinuxCNC halsampler output or a halscope export),
        each file a raw log of one machine axis, read into a trace
        (``features.traces.logs.read_log_trace``).
    channels : str or dict, optional
        A raw log's channels, each name to its PV: ``commanded=PV,motor=PV,load=PV``
        (halsampler: 0-based field numbers or pin names). Required with a raw log, refused
        without one.
    reference_scale : float or (float, float), optional
        A raw log's load side: load position = gain * logged value + offset, in the
        commanded channel's unit (a resolver in counts, a reference counting the other way);
        default: as logged.
    machine : str, optional
        A raw log's machine; default the one the commanded PV's name states (its IOC).
    axis : str, optional
        A raw log's axis; default the one the commanded PV's name states (its axis letter).
    period_s : float, optional
        Sample period of halsampler output [s].

    Returns
    -------
    MonitorResult

    Raises
    ------
    InputError
        A trace breaking the contract, without ``load_mm``, a day given twice, an unknown
        engine; a raw log without ``channels`` or its ``load`` channel, a channel it does not log, an
        axis neither named nor given (``features.traces.logs``), ``channels`` on a trace;
        a day that cannot be physical (``models.condition.lost_motion.check_physical``; nothing is
        written or recorded).
    """
    log = _log_options(format, channels, reference_scale, machine, axis, period_s)
    import pandas as pd

    from models.condition.lost_motion import DAILY_COLUMNS
    from pipeline.engines import map_partitions

    options = {"take_up": float(take_up_mm), "settle_s": float(settle_s)}
    items = _partitions(traces, log)
    frames = map_partitions(partition_days, [(item, options) for item, _ in items],
                            engine=engine, address=address, progress=progress)
    daily = (pd.concat(frames, ignore_index=True) if frames
             else pd.DataFrame(columns=list(DAILY_COLUMNS)))
    _check_each_day_once(daily)
    offsets = _check_physical(frames, [source for _, source in items], log, take_up_mm)
    daily = daily[list(DAILY_COLUMNS)]
    daily = daily.sort_values(["machine_id", "axis", "date"], kind="stable",
                              ignore_index=True)
    axes = [_axis_monitor(group, threshold_um)
            for _, group in daily.groupby(["machine_id", "axis"], sort=True)]
    notes = offsets + _notes(daily)
    for text in notes:
        note(text)
    return MonitorResult(daily=daily, axes=axes, source=_source(traces), engine=engine,
                         parameters={"engine": engine, "threshold_um": threshold_um,
                                     "take_up_mm": take_up_mm, "settle_s": settle_s},
                         notes=notes)


def _log_options(format, channels, reference_scale, machine, axis, period_s) -> dict | None:
    """A raw log's reading options (``features.traces.logs``), or None for trace tables,
    which state their channels, scale, machine and axis themselves."""
    given = {"channels": channels, "reference_scale": reference_scale, "machine": machine,
             "axis": axis, "period_s": period_s}
    if format == "trace":
        name = next((k for k, v in given.items() if v is not None), None)
        if name is not None:
            raise InputError("applies to a raw log (--log-format camonitor or halsampler) "
                             "only; a trace table names its own columns", parameter=name)
        return None
    if channels is None:
        raise InputError(f"a {format} log needs its channels; expected "
                         "commanded=PV,motor=PV,load=PV", parameter="channels")
    if isinstance(channels, str):
        from features.traces.logs import parse_log_channels

        channels = parse_log_channels(channels)
    if "load" not in channels:
        raise InputError(LOAD_NEEDED.replace("column load_mm", "channel load=PV"),
                         parameter="channels")
    return {"format": format, **given, "channels": channels}


def _partitions(traces, log: dict | None = None) -> list:
    """The work items, each with its source (named in errors): a dataset's partitions (read
    by the task), or a table's or raw log's machine axes (read here, whole: a single file
    fits one machine)."""
    import pandas as pd

    from features.traces.io import is_dataset, partitions, read_trace
    from features.traces.validation import check_trace

    if isinstance(traces, pd.DataFrame):
        if log is not None:
            raise InputError(f"format {log['format']!r} reads a log file, not a frame",
                             parameter="format")
        return [(a, "traces") for a in _axes_of(check_trace(traces, "traces"), "traces")]
    items = []
    for path in ([traces] if isinstance(traces, (str, os.PathLike)) else list(traces)):
        if log is not None:
            from features.traces.logs import read_log_trace

            items.extend((a, path) for a in _axes_of(read_log_trace(path, **log), path))
        elif is_dataset(path):
            items.extend((p, os.path.dirname(p.files[0])) for p in partitions(path))
        else:
            items.extend((a, path) for a in _axes_of(read_trace(path), path))
    if not items:
        raise InputError("names no trace; expected one or more files or folders",
                         parameter="traces")
    return items


def _axes_of(trace, source) -> list:
    from features.traces.io import groups

    _require_load(trace, source)
    return groups(trace)


def _require_load(trace, source) -> None:
    from features.traces.contract import LOAD

    if LOAD not in trace:
        raise InputError(LOAD_NEEDED, file=source)


def partition_days(task) -> object:
    """The daily lost motion of one partition: a dataset partition (read here, so each task
    holds one partition only) or a machine axis's trace frame. Pure: the same partition gives
    the same frame on every engine."""
    from features.traces.io import Partition, read_partition
    from models.condition.lost_motion import daily_lost_motion

    item, options = task
    if isinstance(item, Partition):
        trace = read_partition(item)
        _require_load(trace, item.files[0])
    else:
        trace = item
    return daily_lost_motion(trace, **options, travel=True)


def _check_physical(frames: list, sources: list, log: dict | None, take_up_mm: float
                    ) -> list[str]:
    """Refuse a day that cannot be physical (``check_physical``), naming its input and the
    channels as the user named them; the notes of load sides not in the motor's
    coordinates."""
    from models.condition.lost_motion import check_physical, offset_notes

    if log is None:
        names = {k: f"{k}_mm" for k in ("commanded", "motor", "load")}
        remedy = "; expected both positions in mm (deg on a rotary axis) of the axis"
    else:
        names = {k: str(v) for k, v in log["channels"].items()}
        remedy = ("; give the load side's scale with --reference-scale GAIN,OFFSET (Python "
                  "reference_scale=)")
    for frame, source in zip(frames, sources, strict=True):
        check_physical(frame, names, min_travel=take_up_mm, file=source, remedy=remedy)
    return [text for frame in frames
            for text in offset_notes(frame, names, min_travel=take_up_mm)]


def _check_each_day_once(daily) -> None:
    twice = daily.duplicated(["machine_id", "axis", "date"])
    if twice.any():
        r = daily[twice].iloc[0]
        raise InputError(f"machine {r.machine_id} axis {r.axis} on {r.date} is in two inputs; "
                         "expected each day once", parameter="traces")


def _axis_monitor(days, threshold_um) -> AxisMonitor:
    """The drift analysis of one axis's days with a lost motion (``models.condition.drift``)."""
    import numpy as np
    import pandas as pd

    from features.visits import DAYS_PER_MONTH
    from models.condition.drift import analyse_series

    first = days.iloc[0]
    value = days["lost_motion_um"].to_numpy()
    known = ~np.isnan(value)
    out = AxisMonitor(str(first.machine_id), str(first.axis), str(first.unit),
                      days.reset_index(drop=True))
    if known.sum() < 2:
        return out
    date = days["date"].to_numpy()[known]  # ISO dates, parsed as such by numpy
    visits = pd.DataFrame({"machine_id": out.machine_id, "axis": out.axis, "visit": date,
                           "date": date.astype("datetime64[D]").astype("datetime64[us]"),
                           "backlash_um": value[known],
                           "backlash_u_um": days["lost_motion_u_um"].to_numpy()[known]})
    s = analyse_series(visits, threshold_um=threshold_um)
    out.series = s
    out.change_points = [str(s.visits["visit"].iloc[c["index"]]) for c in s.change_points]
    slope = s.trend.get("slope")
    out.slope_um_per_day = (None if slope is None or math.isnan(slope)
                            else round(float(slope) / DAYS_PER_MONTH, 6))
    out.alerts = s.alerts
    return out


def _notes(daily) -> list[str]:
    from models.condition.lost_motion_stream import MIN_CLUSTERS

    notes = []
    loose = daily[daily["lost_motion_um"].notna() & daily["lost_motion_u_um"].isna()]
    if not loose.empty:
        notes.append(
            f"{len(loose)} day(s) have a lost motion without an uncertainty (e.g. "
            f"{loose.iloc[0].machine_id} {loose.iloc[0].axis} on {loose.iloc[0].date}, "
            f"{loose.iloc[0].reversals} reversals): fewer than {MIN_CLUSTERS} moves between "
            "reversals, or a move without which the play cannot be told from the lead error "
            "or the lag, leave the jackknife no degrees of freedom; a store does not record "
            "them")
    blind = daily[daily["lost_motion_um"].isna()]
    if blind.empty:
        return notes
    return notes + [(f"{len(blind)} day(s) show no lost motion (e.g. {blind.iloc[0].machine_id} "
            f"{blind.iloc[0].axis} on {blind.iloc[0].date}): fewer than two reversals took up "
            "the play, or every move ran at one feed without rests, so that lost motion and "
            "servo lag cannot be told apart; they are listed without a value")]


def _source(traces) -> str:
    if isinstance(traces, (str, os.PathLike)):
        return str(traces)
    if isinstance(traces, (list, tuple)):
        return ", ".join(str(t) for t in traces)
    return "traces"
