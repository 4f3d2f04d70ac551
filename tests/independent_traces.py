"""An independent generator of dual-feedback controller traces, written for the tests from the
physics alone (not from the product's twin, ``models.physics``).

Each day an axis runs a minute of routine motion: moves between random positions at a few
feeds, with ramps and dwells. The motor follows the set point through a first-order servo;
the nut trails the motor through a dead zone of the day's clearance; the motor encoder reads
the motor plus the screw's lead error; the scale reads the table with a small latency. So
motor - load = d b/2 + e(x) + v * latency + noise, and b per day is the truth.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.signal import lfilter

FEEDS_MM_MIN = (600.0, 1800.0, 4000.0)


def routine_path(rng, seconds: float, rate_hz: float, travel=(0.0, 300.0),
                 accel_mm_s2: float = 500.0) -> np.ndarray:
    """Set points [mm] of a minute of moves between random positions, each move a
    trapezoidal velocity profile at a random feed, followed by a dwell."""
    n = round(seconds * rate_hz)
    out = np.empty(n)
    x, i = rng.uniform(*travel), 0
    while i < n:
        target = rng.uniform(*travel)
        v = rng.choice(FEEDS_MM_MIN) / 60.0
        d = target - x
        t_acc = v / accel_mm_s2
        if abs(d) < v * t_acc:  # short move: triangular profile
            t_acc = np.sqrt(abs(d) / accel_mm_s2)
            v = accel_mm_s2 * t_acc
        total = 2 * t_acc + max(abs(d) - v * t_acc, 0.0) / v
        tt = np.arange(0.0, total, 1.0 / rate_hz)
        s = np.where(tt < t_acc, 0.5 * accel_mm_s2 * tt ** 2,
                     np.where(tt > total - t_acc,
                              abs(d) - 0.5 * accel_mm_s2 * (total - tt) ** 2,
                              0.5 * accel_mm_s2 * t_acc ** 2 + v * (tt - t_acc)))
        dwell = np.full(int(rng.uniform(0.3, 1.2) * rate_hz), target)
        seg = np.r_[x + np.sign(d) * s, dwell]
        m = min(len(seg), n - i)
        out[i:i + m] = seg[:m]
        i += m
        x = target
    return out


def lead_error_mm(x_mm: np.ndarray) -> np.ndarray:
    """A smooth lead error [mm]: 6 um of slope and bow over 300 mm plus a 0.8 um wave of
    25 mm period (coarser than a screw pitch, so a spline can follow it at 200 Hz)."""
    u = x_mm / 300.0
    return 1e-3 * (4.0 * u - 3.0 * u ** 2 + 0.8 * np.sin(2 * np.pi * x_mm / 25.0))


def axis_days(rng, clearance_um, seconds: float = 60.0, rate_hz: float = 200.0,
              servo_tau_s: float = 0.02, latency_s: float = 0.002, noise_um: float = 0.05):
    """Samples of one axis on several days, one clearance [um] each: (t_s, commanded, motor,
    load), each (days, samples) [s, mm] but t_s (samples,)."""
    clearance_um = np.atleast_1d(np.asarray(clearance_um, float))
    cmd = np.stack([routine_path(rng, seconds, rate_hz) for _ in clearance_um])
    t = np.arange(cmd.shape[1]) / rate_hz
    a = np.exp(-1.0 / (rate_hz * servo_tau_s))
    motor = lfilter([1 - a], [1, -a], cmd, axis=1, zi=a * cmd[:, :1])[0]
    nut = motor - lead_error_mm(motor)
    half = clearance_um / 2000.0
    table = np.empty_like(nut)
    p = nut[:, 0].copy()
    for k in range(nut.shape[1]):  # the dead zone: the table moves only when the nut pushes it
        p = np.minimum(np.maximum(p, nut[:, k] - half), nut[:, k] + half)
        table[:, k] = p
    load = np.stack([np.interp(t - latency_s, t, row) for row in table])
    noise = noise_um / 1000.0
    return (t, cmd, motor + rng.normal(0, noise, motor.shape),
            load + rng.normal(0, noise, load.shape))


def axis_day(rng, clearance_um: float, **options):
    """One day of ``axis_days``: (t_s, commanded, motor, load), each (samples,)."""
    t, cmd, motor, load = axis_days(rng, [clearance_um], **options)
    return t, cmd[0], motor[0], load[0]


def fleet_traces(seed: int = 7, days: int = 30, seconds: float = 60.0, rate_hz: float = 200.0,
                 start: str = "2026-03-01"):
    """Traces of three axes over ``days`` days: X wears steadily, Y is steady, Z wears and is
    adjusted on day 17 (its clearance drops by 4 um). Returns (trace frame, truth frame with
    machine_id, axis, date, lost_motion_um)."""
    rng = np.random.default_rng(seed)
    day = np.arange(days)
    clearance = {"X": 3.0 + 0.05 * day, "Y": np.full(days, 6.0),
                 "Z": 8.0 + 0.08 * day - np.where(day >= 17, 4.0, 0.0)}
    frames, truth = [], []
    for axis, b in clearance.items():
        t, cmd, motor, load = axis_days(rng, b, seconds, rate_hz)
        for d in day:
            begin = pd.Timestamp(start, tz="UTC") + pd.Timedelta(days=int(d), hours=9)
            frames.append(pd.DataFrame({
                "time": begin + pd.to_timedelta(t, unit="s"), "machine_id": "M7",
                "axis": axis, "commanded_mm": cmd[d], "motor_mm": motor[d],
                "load_mm": load[d]}))
            truth.append({"machine_id": "M7", "axis": axis,
                          "date": begin.date().isoformat(), "lost_motion_um": b[d]})
    return pd.concat(frames, ignore_index=True), pd.DataFrame(truth)
