"""Channel updates of one machine axis into samples, bins and closed days.

A source delivers each channel's updates with the server's timestamps, channels interleaved
as the network delivers them. A sample is the axis's channels at one time: every update makes
one, holding each channel's last value, from the first time every channel has one, exactly as
``monitor`` reads a camonitor log (``features.readings.camonitor.read_camonitor``: updates in
time order, the last of equal times). Updates are held until every channel has reported a later
time (a watermark), so a late packet of one channel still lands in order; what is released goes
to the estimator's bins and stream (``models.condition.lost_motion_stream``).
"""

from __future__ import annotations

import numpy as np

from features.readings.errors import InputError
from models.condition.lost_motion_stream import DAY_NS, AxisStream, Binner

CHANNELS = ("commanded", "motor", "load")
# A linear position beyond this [mm] (100 m) is no machine tool's travel: encoder counts.
COUNTS_MM = 1e5
# Intervals kept per day to estimate the source's sampling period (their median).
PERIOD_PROBE = 1000


class AxisFeed:
    """One machine axis: updates in, closed days out (``take``), state as arrays."""

    def __init__(self, config, take_up: float = 0.05, settle_s: float = 0.1):
        self.config = config
        self.held: list[tuple[int, int, int, float]] = []  # (ns, seq, channel, value)
        self.seq = 0
        self.latest = [None, None, None]  # the last time each channel reported [ns]
        self.value = [np.nan, np.nan, np.nan]  # each channel's value as released
        self.binner, self.stream = Binner(), AxisStream(take_up, settle_s)
        self.closed_through = -1  # UTC day number of the last day closed (recorded)
        self.last_sample_ns = None
        self.counts: dict = {}  # day -> (first ns, last ns, samples, first intervals [s])
        self.dropped = 0  # samples of days already closed (after a restart): not doubled
        self.closed: list[dict] = []  # days closed and not yet recorded (the outbox)

    # ------------------------------------------------------------------ updates
    def update(self, channel: int, ns: int, value: float) -> None:
        """One channel's update: its time [ns since the epoch, UTC] and value [mm or deg]."""
        last = self.latest[channel]
        name = self.config.channels[CHANNELS[channel]]
        if last is not None and ns < last:
            raise InputError(f"the source's clock runs backwards on {name} "
                             f"({_iso(ns)} after {_iso(last)}); expected each channel's "
                             "timestamps in order", parameter="config")
        if channel == 2:
            value = self.config.gain * value + self.config.offset
        if abs(value) > COUNTS_MM and self.config.axis not in "ABC":
            raise InputError(f"{name} reads {value:g}, beyond any travel in mm; expected "
                             "positions in mm, not encoder counts (scale them at the source, "
                             "or the load by reference_scale)", parameter="config")
        self.latest[channel] = ns
        self.held.append((ns, self.seq, channel, float(value)))
        self.seq += 1

    def release(self, final: bool = False, period_s: float | None = None) -> int:
        """Samples of the held updates older than every channel's latest (all at ``final``);
        returns how many samples were made."""
        if not self.held:
            return 0
        if final:
            cut = None
        elif any(t is None for t in self.latest):
            return 0
        else:
            cut = min(self.latest)
        self.held.sort()
        n = len(self.held) if cut is None else next(
            (i for i, h in enumerate(self.held) if h[0] >= cut), len(self.held))
        if n == 0:
            return 0
        out_ns, out = [], []
        go, self.held = self.held[:n], self.held[n:]
        for i, (ns, _, channel, value) in enumerate(go):
            self.value[channel] = value
            if i + 1 < len(go) and go[i + 1][0] == ns:
                continue  # the last update of equal times makes the sample
            if not np.isnan(self.value).any():
                out_ns.append(ns)
                out.append(tuple(self.value))
        if out_ns:
            self._samples(np.array(out_ns, np.int64), np.array(out, float), period_s)
        return len(out_ns)

    def _samples(self, ns: np.ndarray, values: np.ndarray, period_s) -> None:
        day = ns // DAY_NS
        keep = day > self.closed_through
        self.dropped += int((~keep).sum())
        ns, values, day = ns[keep], values[keep], day[keep]
        if not len(ns):
            return
        self.last_sample_ns = int(ns[-1])
        for d in np.unique(day):
            at = day == d
            self._count(int(d), ns[at])
            for done in self.stream.feed(*self.binner.add(ns[at], *values[at].T)):
                self._closed(done, period_s)

    def _count(self, d: int, ns: np.ndarray) -> None:
        """Per day: first and last sample [ns], samples received, the first intervals [s]."""
        first, last, count, dts = self.counts.get(d, (int(ns[0]), None, 0, []))
        if last is not None and len(dts) < PERIOD_PROBE:
            dts.append((int(ns[0]) - last) * 1e-9)
        room = PERIOD_PROBE - len(dts)
        if room > 0 and len(ns) > 1:
            dts.extend((np.diff(ns[:room + 1]) * 1e-9).tolist())
        self.counts[d] = (first, int(ns[-1]), count + len(ns), dts)

    def _closed(self, done: tuple, period_s) -> None:
        day, fit = done
        self.closed.append(self._day_row(day, fit, period_s))
        self.closed_through = max(self.closed_through, day)
        self.counts.pop(day, None)

    def _day_row(self, day: int, fit: tuple, period_s) -> dict:
        """The day's record fields, with its gap: samples expected over the span it was
        watched (at the source's period, else the median of its first intervals) against
        samples received."""
        from features.readings.schema import deviation_scale

        scale = deviation_scale(self.config.axis)
        first, last, count, dts = self.counts.get(day, (0, 0, 0, []))
        period = period_s or (float(np.median(dts)) if dts else None)
        expected = round((last - first) * 1e-9 / period) + 1 if period else count
        expected = max(expected, count)
        return {"machine_id": self.config.machine_id, "axis": self.config.axis,
                "date": str(np.datetime64(int(day), "D")),
                "lost_motion_um": fit[0] * scale, "lost_motion_u_um": fit[1] * scale,
                "reversals": int(fit[2]), "samples": int(fit[3]), "lag_s": fit[4],
                "control_points": int(fit[5]), "samples_expected": expected,
                "samples_received": count,
                "coverage": round(count / expected, 6) if expected else 0.0}

    def stop(self, period_s: float | None = None) -> None:
        """Release everything and close the open day (a bounded run is over)."""
        self.release(final=True, period_s=period_s)
        for done in self.stream.feed(*self.binner.flush()):
            self._closed(done, period_s)
        for done in self.stream.close():
            self._closed(done, period_s)

    # ------------------------------------------------------------------ state
    def to_arrays(self) -> dict:
        held = np.array([(h[0], h[1], h[2]) for h in self.held], np.int64).reshape(-1, 3)
        out = {"held_keys": held, "held_values": np.array([h[3] for h in self.held], float),
               "latest": np.array([-1 if t is None else t for t in self.latest], np.int64),
               "value": np.array(self.value, float),
               "counters": np.array([self.seq, self.closed_through,
                                     -1 if self.last_sample_ns is None else self.last_sample_ns,
                                     self.dropped], np.int64),
               "count_days": np.array([[d, c[0], c[1], c[2]] for d, c in self.counts.items()],
                                      np.int64).reshape(-1, 4)}
        for d, c in self.counts.items():
            out[f"dts_{d}"] = np.array(c[3], float)
        out.update({f"s_{k}": v for k, v in self.stream.to_arrays().items()})
        out.update({f"b_{k}": v for k, v in self.binner.to_arrays().items()})
        return out

    def load(self, arrays) -> None:
        keys, values = arrays["held_keys"], arrays["held_values"]
        self.held = [(int(k[0]), int(k[1]), int(k[2]), float(v)) for k, v in zip(keys, values)]
        self.latest = [None if t < 0 else int(t) for t in arrays["latest"]]
        self.value = [float(v) for v in arrays["value"]]
        self.seq, self.closed_through, last, self.dropped = (
            int(v) for v in arrays["counters"])
        self.last_sample_ns = None if last < 0 else last
        self.counts = {int(d): (int(f), int(t), int(n), [float(v) for v in arrays[f"dts_{d}"]])
                       for d, f, t, n in arrays["count_days"]}
        self.stream = AxisStream.from_arrays(
            {k[2:]: v for k, v in arrays.items() if k.startswith("s_")})
        self.binner = Binner.from_arrays(
            {k[2:]: v for k, v in arrays.items() if k.startswith("b_")})


def _iso(ns: int) -> str:
    return str(np.datetime64(int(ns), "ns"))[:26]
