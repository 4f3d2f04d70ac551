"""The watcher's I/O loop: one source, every axis's feed, the state in the store.

Every ``TICK_S`` the feeds release what every channel has passed; a closed day goes to the
state's outbox, the state is saved, the day recorded, the outbox emptied and the state saved
again, so a watcher killed at any instant records each day once (a record already stored is
left as it is: ``pipeline.store.records.record``). The state is saved every ``SAVE_S`` besides.
SIGTERM saves and stops without closing the open day (it resumes at the next start); the end
of ``--until``/``--for`` closes and records the open days.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import signal
import threading
import time

import numpy as np

from features.readings.errors import InputError
from pipeline.live.feed import CHANNELS, AxisFeed
from pipeline.live.sources import SOURCES

TICK_S = 0.1
SAVE_S = 1.0
STATUS_S = 5.0


class Watcher:
    def __init__(self, config, store, *, take_up: float, settle_s: float, status=None):
        from pipeline.store.live import live_folder

        self.config, self.store, self.status = config, store, status or (lambda line: None)
        self.folder = live_folder(store)
        self.name = f"watch__{_slug(config.path)}"
        self.feeds = {a.key: AxisFeed(a, take_up, settle_s) for a in config.axes}
        self.route: dict[str, list] = {}
        for a in config.axes:
            for i, channel in enumerate(CHANNELS):
                self.route.setdefault(a.channels[channel], []).append((self.feeds[a.key], i))
        self.source = SOURCES[config.protocol](config, self.emit, self._event)
        self.recorded: list[dict] = []
        self.updates = 0
        self.stopping = False
        self.error: InputError | None = None
        self._restore()

    # ------------------------------------------------------------------ state
    def _restore(self) -> None:
        from pipeline.store.live import load_state

        saved = load_state(self.folder, self.name, "state")
        if saved is None:
            return
        arrays, meta = saved
        for key, feed in self.feeds.items():
            prefix = f"{key}|"
            mine = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
            if mine:
                feed.load(mine)
                feed.closed = list(meta.get("outbox", {}).get(key, []))
        self.source.restore(meta.get("source", {}))

    def save(self) -> None:
        from pipeline.store.live import save_state

        arrays = {}
        for key, feed in self.feeds.items():
            arrays.update({f"{key}|{k}": v for k, v in feed.to_arrays().items()})
        axes = [{"machine_id": f.config.machine_id, "axis": f.config.axis,
                 "last_sample": _iso(f.last_sample_ns),
                 "stale_after_s": f.config.stale_after_s, "source": self.config.path}
                for f in self.feeds.values()]
        meta = {"source": self.source.state(), "axes": axes,
                "outbox": {k: f.closed for k, f in self.feeds.items() if f.closed}}
        save_state(self.folder, self.name, "state", arrays, meta)

    def flush_days(self) -> None:
        """Record the closed days (saved first, so a kill in between records them later)."""
        if not any(f.closed for f in self.feeds.values()):
            return
        self.save()
        from pipeline.store.records import RECORD_FORMAT, record

        days = [d for f in self.feeds.values() for d in f.closed]
        records = [{"kind": "trace", "format": RECORD_FORMAT, "machine_id": d["machine_id"],
                    "axis": d["axis"], "date": d["date"],
                    "lost_motion_um": float(d["lost_motion_um"]),
                    "lost_motion_u_um": float(d["lost_motion_u_um"]),
                    "reversals": int(d["reversals"]), "source": f"watch {self.config.path}",
                    "samples_expected": int(d["samples_expected"]),
                    "samples_received": int(d["samples_received"]),
                    "coverage": float(d["coverage"])}
                   for d in days if _finite(d["lost_motion_um"], d["lost_motion_u_um"])]
        if records:
            record(self.store, "trace", records)
        for d in days:
            self._event({"event": "day_recorded" if _finite(d["lost_motion_um"]) else
                         "day_without_value", **{k: _plain(v) for k, v in d.items()}})
        self.recorded.extend(days)
        for f in self.feeds.values():
            f.closed = []
        self.save()

    # ------------------------------------------------------------------ updates
    def emit(self, name: str, ns: int, value: float) -> None:
        self.updates += 1
        try:
            for feed, channel in self.route.get(name, ()):
                feed.update(channel, ns, value)
        except InputError as err:
            # a protocol library calls this from its own callbacks, which swallow errors:
            # kept for the loop to raise (the clock ran backwards, a value in counts)
            self.error = self.error or err

    def _event(self, line: dict) -> None:
        self.status({"time": _iso(time.time_ns()), **line})

    def tick(self, final: bool = False) -> None:
        for feed in self.feeds.values():
            feed.release(final=final, period_s=self.config.period_s)
        self.flush_days()

    # ------------------------------------------------------------------ running
    async def run(self, seconds: float | None) -> None:
        loop = asyncio.get_running_loop()
        await self.source.start(self.config.timeout_s)
        self._event({"event": "started", "protocol": self.config.protocol,
                     "axes": list(self.feeds)})
        self.flush_days()  # an outbox left by a watcher killed before recording
        task = asyncio.create_task(self.source.run())
        end = math.inf if seconds is None else loop.time() + seconds
        saved = status = loop.time()
        try:
            while not self.stopping and loop.time() < end:
                await asyncio.sleep(TICK_S)
                if task.done():
                    task.result()  # a source's own error (InputError: the clock went back)
                if self.error is not None:
                    raise self.error
                self.tick()
                now = loop.time()
                if now - saved >= SAVE_S:
                    self.save()
                    saved = now
                if now - status >= STATUS_S:
                    self._event({"event": "status", "updates": self.updates,
                                 "last_sample": {k: _iso(f.last_sample_ns)
                                                 for k, f in self.feeds.items()}})
                    status = now
        finally:
            task.cancel()
            close = getattr(self.source, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):  # the server may be gone already
                    await close()
        if self.stopping:  # SIGTERM: keep the open day for the next start
            self.tick()
            self.save()
            self._event({"event": "stopped", "open_days_kept": True})
            return
        if hasattr(self.source, "poll"):
            self.source.poll()  # what the file holds at the end
        for feed in self.feeds.values():
            feed.stop(self.config.period_s)
        self.flush_days()
        self.save()
        self._event({"event": "stopped", "open_days_kept": False})


def run_watch(config, store, *, seconds: float | None, take_up: float, settle_s: float,
              status=None) -> Watcher:
    """Run a watcher until ``seconds`` pass (None: until SIGTERM or SIGINT)."""
    watcher = Watcher(config, store, take_up=take_up, settle_s=settle_s, status=status)

    async def main():
        loop = asyncio.get_running_loop()
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                loop.add_signal_handler(sig, lambda: setattr(watcher, "stopping", True))
        await watcher.run(seconds)

    asyncio.run(main())
    return watcher


def _slug(path: str) -> str:
    import hashlib
    import os

    stem = os.path.splitext(os.path.basename(path))[0] or "watch"
    return f"{stem}-{hashlib.sha256(os.path.abspath(path).encode()).hexdigest()[:8]}"


def _iso(ns) -> str | None:
    return None if ns is None else str(np.datetime64(int(ns), "ns"))[:26] + "Z"


def _finite(*values) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


def _plain(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value.item() if hasattr(value, "item") else value
