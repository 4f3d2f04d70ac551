"""An independent ballbar generator for testing the circle diagnosis (not the product's twin, not
the diagnosis's signature model).

It moves two axes round a circle in time and measures the distance between the pivot and the
tool ball, with its own forms of every effect:

- play: a dead band between motor and load, taken up over the motor travel ``b`` (not a step);
- friction spike: the load sticks after a reversal, ``h (d/w) exp(1 - d/w)``: rising to its
  peak ``h`` at ``w`` degrees of travel, then falling (the model fits a decaying exponential);
- servo lag: each axis follows the command ``dt`` seconds late (a time shift, not a linearised
  velocity term);
- squareness: the second axis leans towards the first, ``x += a y``; scale: ``x *= 1 + s``;
- the pivot off the programmed centre, a slow thermal drift of the bar, white noise, a
  sampling step that is not a divisor of 360 deg and a start angle that is not 0.

Conventions the diagnosis must share (docs/circle.md): CCW is increasing angle;
``squareness`` > 0 when the second axis leans towards the first (``x += a y``);
``scale mismatch`` = scale error of the first axis minus that of the second;
``servo mismatch`` = lag of the first axis minus that of the second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Truth:
    machine_id: str
    play_um: tuple[float, float]          # (first axis, second axis)
    spike_um: tuple[float, float]
    spike_width_deg: float
    squareness_um_per_m: float
    scale_ppm: tuple[float, float]
    lag_ms: tuple[float, float]
    pivot_um: tuple[float, float]


def random_truth(rng: np.random.Generator, machine_id: str) -> Truth:
    return Truth(
        machine_id=machine_id,
        play_um=tuple(rng.uniform(2.0, 14.0, 2)),
        spike_um=tuple(rng.uniform(1.0, 5.0, 2)),
        spike_width_deg=float(rng.uniform(1.5, 4.0)),
        squareness_um_per_m=float(rng.uniform(-40.0, 40.0)),
        scale_ppm=tuple(rng.uniform(-30.0, 30.0, 2)),
        lag_ms=tuple(rng.uniform(0.0, 3.0, 2)),
        pivot_um=tuple(rng.uniform(-30.0, 30.0, 2)),
    )


def _dead_band(motor: np.ndarray, play: float, start: float) -> np.ndarray:
    """Load position behind a play ``play`` (same unit as ``motor``), starting at ``start``."""
    load = np.empty_like(motor)
    last = start
    half = play / 2.0
    for i, m in enumerate(motor):
        if m - last > half:
            last = m - half
        elif last - m > half:
            last = m + half
        load[i] = last
    return load


def _stick(motor: np.ndarray, travel_deg: np.ndarray, height: float, width: float) -> np.ndarray:
    """Friction stick after each reversal of ``motor``: against the new motion, shaped
    ``height (d/w) exp(1 - d/w)`` over the travel ``d`` [deg] since that reversal."""
    v = pd.Series(np.sign(np.diff(motor, prepend=motor[0]))).replace(0.0, np.nan)
    v = v.ffill().bfill().to_numpy()  # a sample standing still keeps the last direction
    out = np.zeros_like(motor)
    reversals = np.flatnonzero(v[1:] != v[:-1]) + 1
    for r in reversals:
        d = travel_deg[r:] - travel_deg[r]
        out[r:] += -v[r] * height * (d / width) * np.exp(1.0 - d / width)
    return out


def ballbar_run(truth: Truth, direction: str, *, radius_mm: float = 150.0,
                feed_mm_min: float = 1000.0, step_deg: float = 0.6173, noise_um: float = 0.15,
                drift_um: float = 0.3, start_deg: float | None = None,
                rng: np.random.Generator) -> pd.DataFrame:
    """One run: readings of the radial deviation [um] at angles from ``start_deg`` (default a
    random start)."""
    s = 1.0 if direction == "CCW" else -1.0
    omega = feed_mm_min / 60.0 / radius_mm                       # rad/s
    fine = 0.04                                                  # deg, the simulation step
    lead_in = 180.0                                              # deg before the data
    start = float(rng.uniform(0.0, 360.0)) if start_deg is None else start_deg
    travel = np.arange(0.0, lead_in + 360.0 + 3 * step_deg, fine)   # deg travelled
    time = np.radians(travel) / omega
    theta0 = np.radians(start - s * lead_in)
    um = 1e-3
    pos = []
    for k, trig in enumerate((np.cos, np.sin)):
        lag = truth.lag_ms[k] * 1e-3
        motor = radius_mm * trig(theta0 + s * omega * (time - lag))     # mm
        load = _dead_band(motor, truth.play_um[k] * um, motor[0] - truth.play_um[k] * um / 2)
        load += _stick(motor, travel, truth.spike_um[k] * um, truth.spike_width_deg)
        pos.append(load * (1.0 + truth.scale_ppm[k] * 1e-6))
    x, y = pos
    x = x + truth.squareness_um_per_m * 1e-6 * y
    px, py = (p * um for p in truth.pivot_um)
    length = np.hypot(x - px, y - py)
    bar = length - radius_mm                                     # mm
    keep_travel = lead_in + np.arange(0.0, 360.0, step_deg)      # the data capture
    dev = np.interp(keep_travel, travel, bar) / um
    dev += drift_um * (keep_travel - lead_in) / 360.0 + rng.normal(0.0, noise_um, dev.size)
    angle = np.mod(start + s * (keep_travel - lead_in), 360.0)
    return pd.DataFrame({"angle_deg": angle, "deviation_um": dev})


def fleet(n: int = 6, seed: int = 7, **run) -> tuple[pd.DataFrame, list[Truth]]:
    """``n`` machines, XY plane, R 150 mm, CW and CCW: the readings table and the truths."""
    rng = np.random.default_rng(seed)
    frames, truths = [], []
    for m in range(n):
        truth = random_truth(rng, f"M{m + 1}")
        truths.append(truth)
        for direction in ("CW", "CCW"):
            r = ballbar_run(truth, direction, rng=rng, **run)
            frames.append(r.assign(test_id=f"{truth.machine_id}-{direction}",
                                   machine_id=truth.machine_id, plane="XY",
                                   direction=direction, radius_mm=run.get("radius_mm", 150.0),
                                   feed_mm_min=run.get("feed_mm_min", 1000.0)))
    columns = ["test_id", "machine_id", "plane", "direction", "angle_deg", "radius_mm",
               "feed_mm_min", "deviation_um"]
    return pd.concat(frames, ignore_index=True)[columns], truths
