"""The twin's controller traces: routine motion of a feed axis logged by the motor encoder and
the load-side scale, day after day, with the truth.

Each logged day an axis runs a routine program (moves of 2-80 mm either way within the
travel at a few feeds, trapezoidal velocity profiles, dwells) for ``seconds`` at ``rate_hz``.
The chain is the twin's own (``models.physics.axis``, ``models.physics.effects``):

- the motor follows the set point through the position loop, a first-order lag of time
  constant 1 / Kv (following error v / Kv);
- the motor encoder reads the motor; the nut trails it by the screw's lead error
  (``lead_error_profile`` plus ``lead_error_periodic``, the same both ways);
- the table follows the nut through the play operator (``axis.play``) of the day's width
  (``effects.lost_motion_um``: the enabled lost-motion effects, growing with wear, reset by an
  adjustment);
- the scale reads the table ``scale_latency_s`` late, and both channels add white noise.

So motor - load = d b/2 + e(x) + v * latency + noise, and b per axis and day is the truth
(``truth``: ``lost_motion_um``). Units: mm and um on a linear axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from models.physics import effects
from models.physics.axis import play


def _axes() -> dict:
    return {"X": {"b0_um": 3.0, "wear_um_per_day": 0.04},
            "Y": {"b0_um": 6.0, "wear_um_per_day": 0.0},
            "Z": {"b0_um": 8.0, "wear_um_per_day": 0.06, "adjusted_day": 17,
                  "adjusted_b0_um": 4.0}}


@dataclass
class TraceCampaign:
    """A logging campaign of one machine's axes.

    Attributes
    ----------
    machine_id : str
    axes : dict
        Axis name -> ``b0_um`` (clearance on the first day [um]), ``wear_um_per_day`` (its
        growth [um/day]) and optionally ``adjusted_day`` (the day index an adjustment resets
        it to ``adjusted_b0_um``, from which it grows again).
    days, every_days : int
        Logged days, and the days between two of them.
    start : str
        First day (UTC), ISO 8601.
    seconds, rate_hz : float
        Length of each day's log [s] and the sampling rate [Hz] (100-1000 Hz).
    travel_mm : tuple
        Travel of the routine moves [mm].
    feeds_mm_min : tuple
        Feeds the routine program uses [mm/min].
    accel_mm_s2 : float
        Acceleration of the velocity profiles [mm/s²].
    kv_per_s : float
        Position-loop gain Kv [1/s].
    scale_latency_s : float
        How late the scale's reading is against the encoder's [s].
    noise_um : float
        White noise of each channel [um].
    lead : dict
        Effect name -> parameters of the lead error (``models.physics.effects``).
    """

    machine_id: str = "M01"
    axes: dict = field(default_factory=_axes)
    days: int = 30
    every_days: int = 1
    start: str = "2026-03-02"
    seconds: float = 60.0
    rate_hz: float = 200.0
    travel_mm: tuple = (0.0, 350.0)
    feeds_mm_min: tuple = (500.0, 2000.0, 5000.0)
    accel_mm_s2: float = 800.0
    kv_per_s: float = 40.0
    scale_latency_s: float = 0.001
    noise_um: float = 0.05
    lead: dict = field(default_factory=lambda: {
        "lead_error_profile": {"p1_um": 3.0, "p2_um": -2.0, "p3_um": 2.5},
        "lead_error_periodic": {"amplitude_um": 0.4, "pitch_mm": 20.0}})


def clearance_um(axis: dict, day: np.ndarray) -> np.ndarray:
    """The play width b [um] on each day index: b0 + wear x day, and after an adjustment
    ``adjusted_b0_um`` + wear x (day - adjusted_day)."""
    day = np.asarray(day, float)
    b = axis["b0_um"] + axis.get("wear_um_per_day", 0.0) * day
    if "adjusted_day" in axis:
        after = day >= axis["adjusted_day"]
        b = np.where(after, axis["adjusted_b0_um"] + axis.get("wear_um_per_day", 0.0)
                     * (day - axis["adjusted_day"]), b)
    return b


def routine(rng: np.random.Generator, c: TraceCampaign, days: int) -> np.ndarray:
    """Set points [mm], shape (days, samples): moves of 2-80 mm either way within the travel
    at the campaign's feeds, each a trapezoidal velocity profile, then a dwell of 0.2-1.5 s."""
    n = round(c.seconds * c.rate_hz)
    out = np.empty((days, n))
    for d in range(days):
        pieces, length, x = [], 0, rng.uniform(*c.travel_mm)
        while length < n:
            # part-program moves: 2-80 mm either way, kept within the travel
            target = float(np.clip(x + rng.choice((-1, 1)) * rng.uniform(2.0, 80.0),
                                   *c.travel_mm))
            move = _trapezoid(target - x, rng.choice(c.feeds_mm_min) / 60.0, c.accel_mm_s2,
                              c.rate_hz)
            pieces += [x + move, np.full(int(rng.uniform(0.2, 1.5) * c.rate_hz), target)]
            length += len(move) + len(pieces[-1])
            x = target
        out[d] = np.concatenate(pieces)[:n]
    return out


def _trapezoid(distance: float, v: float, a: float, rate_hz: float) -> np.ndarray:
    """Travel along one move [mm] sampled at ``rate_hz``: accelerate at ``a`` to ``v``, cruise,
    brake (a triangle when the move is too short to reach ``v``)."""
    s_total = abs(distance)
    v = min(v, np.sqrt(s_total * a))
    t_acc = v / a
    total = 2 * t_acc + (s_total - v * t_acc) / v if v > 0 else 0.0
    t = np.arange(1, int(np.ceil(total * rate_hz)) + 1) / rate_hz
    t = np.minimum(t, total)
    s = np.where(t < t_acc, 0.5 * a * t ** 2,
                 np.where(t > total - t_acc, s_total - 0.5 * a * (total - t) ** 2,
                          v * (t - 0.5 * t_acc)))
    return np.sign(distance) * s


def servo(commanded: np.ndarray, kv_per_s: float, rate_hz: float) -> np.ndarray:
    """Motor positions [mm] of a first-order position loop, rows of ``commanded``:
    dm/dt = Kv (c - m), exact for a set point held over each sample."""
    from scipy.signal import lfilter

    keep = np.exp(-kv_per_s / rate_hz)
    return lfilter([1 - keep], [1, -keep], commanded, axis=1,
                   zi=keep * commanded[:, :1])[0]


def simulate_traces(campaign: TraceCampaign | None = None, seed: int = 0):
    """The campaign's traces and their truth.

    Returns
    -------
    trace : DataFrame
        The trace table (docs/data-contract.md section 10): time, machine_id, axis,
        commanded_mm, motor_mm, load_mm, following_error_mm.
    truth : DataFrame
        Per axis and day: machine_id, axis, date, lost_motion_um (the play width b [um]),
        event ("adjustment" on the day one took effect, else "").
    """
    c = campaign or TraceCampaign()
    rng = np.random.default_rng(seed)
    day_index = np.arange(c.days) * c.every_days
    starts = pd.Timestamp(c.start, tz="UTC") + pd.to_timedelta(day_index, unit="D") \
        + pd.Timedelta(hours=8)
    t = np.arange(round(c.seconds * c.rate_hz)) / c.rate_hz
    frames, truth = [], []
    for name, axis in c.axes.items():
        width = clearance_um(axis, day_index)
        commanded = routine(rng, c, c.days)
        motor = servo(commanded, c.kv_per_s, c.rate_hz)
        lead_um = sum(effects.contribution(e, motor, 0, {}, **p) for e, p in c.lead.items())
        table = play(motor - lead_um / 1000.0,
                     effects.lost_motion_um({"backlash": {"b0_um": width[:, None]}}, motor, {}))
        load = np.stack([np.interp(t - c.scale_latency_s, t, row) for row in table])
        noise = c.noise_um / 1000.0
        motor_read = motor + rng.normal(0.0, noise, motor.shape)
        load_read = load + rng.normal(0.0, noise, load.shape)
        for d, begin in enumerate(starts):
            frames.append(pd.DataFrame({
                "time": begin + pd.to_timedelta(t, unit="s"), "machine_id": c.machine_id,
                "axis": name, "commanded_mm": commanded[d], "motor_mm": motor_read[d],
                "load_mm": load_read[d], "following_error_mm": commanded[d] - motor[d]}))
        adjusted = axis.get("adjusted_day")
        truth.append(pd.DataFrame({
            "machine_id": c.machine_id, "axis": name,
            "date": [s.date().isoformat() for s in starts], "lost_motion_um": width,
            "event": ["adjustment" if adjusted is not None and i >= adjusted
                      and (k == 0 or day_index[k - 1] < adjusted) else ""
                      for k, i in enumerate(day_index)]}))
    return pd.concat(frames, ignore_index=True), pd.concat(truth, ignore_index=True)
