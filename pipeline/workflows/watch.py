"""Watch: a live controller feed into each machine axis's daily lost motion, between laser
visits (docs/watch.md).

>>> import backlash as bl
>>> bl.watch("WATCH.toml", store="fleet/", seconds=3600)   # doctest: +SKIP

A long-running job: the estimator is pure (``models.condition.lost_motion_stream``: per move window the
fit's statistics, per day one combiner, the same as ``monitor``'s), the I/O loop lives in
``pipeline.live`` and the open days' state in the store (``pipeline.store.live``).
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from numbers import Real

from features.readings.errors import InputError
from pipeline.results import Result
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import Param, python_only

_POSITIVE = Interval(Real, 0, None, closed="neither")
# One call as the command line and Python spell it (tests/test_runner.py's agreement): a
# finished log read for a second, its day closed and recorded.
EXAMPLE = (
    ["{watch}", "--store", "{store}", "--for", "1"],
    {"config": "{watch}", "store": "{store}", "seconds": 1.0},
)

PARAMETERS = {
    "config": Param((str, os.PathLike), flag="WATCH"),
    "store": Param((str, os.PathLike, "pipeline.store.base.Store"), metavar="STORE",
                   required=True),
    "until": Param((str, None), metavar="TIME"),
    "seconds": Param((_POSITIVE, None), flag="--for", metavar="SECONDS"),
    "take_up_mm": Param((_POSITIVE,), metavar="X"),
    "settle_s": python_only(Interval(Real, 0, None, closed="left")),
    "status": python_only(None, callable),
}


@dataclass
class WatchResult(Result):
    """What one run of a watcher closed.

    Attributes
    ----------
    days : list of dict
        Per machine axis and day closed: ``lost_motion_um``, ``lost_motion_u_um`` (um, arcsec
        on a rotary axis), ``reversals``, ``samples``, ``samples_expected``,
        ``samples_received``, ``coverage``.
    updates : int
        Channel updates received.
    """

    days: list = field(default_factory=list)
    updates: int = 0
    config: str = ""

    def to_dict(self) -> dict:
        return {"days": self.days, "updates": self.updates, "notes": list(self.notes)}


def watch(config, *, store, until: str | None = None, seconds: float | None = None,
          take_up_mm: float = 0.05, settle_s: float = 0.1, status=None) -> WatchResult:
    """Watch a live feed and record each machine axis's daily lost motion in ``store``.

    Parameters
    ----------
    config : str or path-like
        WATCH.toml (SCHEMA section 14, docs/watch.md): the source (ca, pva, opcua or log) and
        the channels of each machine axis.
    store : str, path-like or Store
        A fleet store folder (made by ``ingest``): where the days are recorded and the open
        days kept.
    until : str, optional
        Stop at this time (ISO 8601, UTC unless it says); the open days are closed and
        recorded.
    seconds : float, optional
        Stop after this many seconds; the open days are closed and recorded. Default: run
        until SIGTERM, which keeps them open.
    take_up_mm : float
        Travel after a reversal past which the play is taken up [mm or deg]; larger than any
        lost motion (as ``monitor``).
    settle_s : float
        As ``monitor``: time after an acceleration before a sample counts as steady [s].
    status : callable, optional
        ``status(line)`` per event (a dict: started, day_recorded, source_down, status, ...).

    Returns
    -------
    WatchResult

    Raises
    ------
    InputError
        A bad WATCH.toml (a channel feeding two axes, no load channel, an unknown protocol), a
        PV or node that does not exist or a source that does not answer within its
        ``timeout_s``, a channel in another unit, a source whose clock runs backwards, a
        store that cannot be written.
    """
    if until is not None and seconds is not None:
        raise InputError("give --until or --for, not both", parameter="until")
    if until is not None:
        seconds = _seconds_until(until)
    from pipeline.live.config import read_config
    from pipeline.live.loop import run_watch

    settings = read_config(config)
    _check_writable(store)  # opened by the runner (``Workflow.store_access``)
    watcher = run_watch(settings, store, seconds=seconds, take_up=float(take_up_mm),
                        settle_s=float(settle_s), status=status)
    days = [{k: _plain(v) for k, v in d.items()} for d in watcher.recorded]
    return WatchResult(days=days, updates=watcher.updates, config=str(config))


def _seconds_until(text: str) -> float:
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise InputError(f"{text!r} is not a time; expected ISO 8601 (2026-03-02T18:00)",
                         parameter="until") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    left = (when - dt.datetime.now(dt.UTC)).total_seconds()
    if left <= 0:
        raise InputError(f"{text} has passed; expected a time to come", parameter="until")
    return left


def _check_writable(store) -> None:
    """Refuse a store whose live folder cannot be written, before any work."""
    from pipeline.store.live import live_folder

    folder = live_folder(store)
    try:
        folder.mkdir(exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise InputError(f"cannot write the watcher's state in the store ({err.strerror})",
                         file=str(folder), parameter="store") from None


def _plain(value):
    import math

    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value.item() if hasattr(value, "item") else value
