"""Pairs of hidden effects from a third generator, written without the twin's code or
functional forms (it never imports ``models``), to test that the missing-effect search finds
both members of a pair.

Design: six linear tests (three feeds x two dwells) of an axis with an indirect measuring
system, eleven irregular targets over 320 mm, five cycles, 0.3 um reading noise, a laser
datum per test; machine temperature, air temperature, pressure and humidity change between
the tests and drift within each (a weather front moves the pressure during a test). The
baseline is a clearance of 2.5 um and a lead error of 10 um/m. Forms of the hidden effects:

=====================  ==================================================================
backlash_position      raised-cosine worn zone: +2.6 um at 35 % of the travel, zero
                       beyond 30 % of the travel either side
backlash_feed          saturating friction: 1.8 um (1 - exp(-feed / 600 mm/min))
backlash_temperature   -0.55 um/K against 20 degC
reversal_profile       hysteresis changing sign along the screw: reversal value
                       +5 um cos(1.6 pi x / L) on top of the clearance's -2.5 um
lead_error_profile     piecewise-linear kink: a triangle of 3 um peaking at 60 % of the
                       travel
thermal_expansion      11 um/(m K) from a fixed bearing at x = 0
thermal_drift          hyperbolic warm-up 2.4 um t / (t + 600 s)
air_refraction         -0.928 ppm/K, +0.2683 ppm/hPa, -0.0086 ppm/%RH of the air, read
                       per reading from the logged air state
=====================  ==================================================================
"""

from __future__ import annotations

import numpy as np
import pandas as pd

START = pd.Timestamp("2026-05-04 07:30")
LENGTH = 320.0
PAIRS = (
    ("backlash_position", "air_refraction"),
    ("reversal_profile", "lead_error_profile"),
    ("backlash_feed", "thermal_drift"),
    ("reversal_profile", "air_refraction"),
    ("backlash_temperature", "lead_error_profile"),
    ("thermal_expansion", "backlash_position"),
    ("backlash_feed", "reversal_profile"),
    ("thermal_drift", "air_refraction"),
)


def _targets(rng) -> np.ndarray:
    t = np.linspace(0.0, LENGTH, 11)
    t[1:-1] += rng.uniform(-0.25, 0.25, 9) * LENGTH / 10
    return np.round(t, 2)


def _order(n: int, cycles: int):
    """(target index, direction) of a linear ISO 230-2 test, in reading order."""
    one = [(i, 1.0) for i in range(n)] + [(i, -1.0) for i in reversed(range(n))]
    return [(i, d, c) for c in range(1, cycles + 1) for i, d in one]


def generate(hidden, seed: int, noise_um: float = 0.3) -> pd.DataFrame:
    """Readings (docs/data-contract.md columns) with the effects ``hidden`` added."""
    rng = np.random.default_rng(50_000 + seed)
    hidden = set(hidden)
    x_t = _targets(rng)
    frames = []
    for k, (feed, dwell) in enumerate((f, d) for f in (250.0, 700.0, 1600.0)
                                      for d in (1.5, 6.0)):
        order = _order(len(x_t), 5)
        idx = np.array([o[0] for o in order])
        d = np.array([o[1] for o in order])
        cycle = np.array([o[2] for o in order])
        x = x_t[idx]
        seconds = np.cumsum(np.full(len(x), dwell + 60.0 * 32.0 / feed))
        frac = seconds / seconds[-1]
        machine = 19.0 + 3.5 * rng.random() + 0.6 * frac
        ambient = 19.5 + 2.0 * rng.random() + 0.3 * frac
        pressure = 1000.0 + 25.0 * rng.random() - 3.0 * frac
        humidity = 35.0 + 25.0 * rng.random() + 2.0 * frac
        b = np.full(len(x), 2.5)
        if "backlash_position" in hidden:
            u = np.clip((x - 0.35 * LENGTH) / (0.3 * LENGTH), -1.0, 1.0)
            b += 2.6 * 0.5 * (1 + np.cos(np.pi * u))
        if "backlash_feed" in hidden:
            b += 1.8 * (1 - np.exp(-feed / 600.0))
        if "backlash_temperature" in hidden:
            b += -0.55 * (machine - 20.0)
        e = -d * np.maximum(b, 0.0) / 2 + 10.0 * x / 1000.0
        if "reversal_profile" in hidden:
            e += d * 5.0 * np.cos(1.6 * np.pi * x / LENGTH) / 2
        if "lead_error_profile" in hidden:
            e += 3.0 * np.maximum(0.0, 1 - np.abs(x - 0.6 * LENGTH) / (0.4 * LENGTH))
        if "thermal_expansion" in hidden:
            e += 11.0 * (machine - 20.0) * x / 1000.0
        if "thermal_drift" in hidden:
            e += 2.4 * seconds / (seconds + 600.0)
        if "air_refraction" in hidden:
            ppm = (-0.928 * (ambient - 20.0) + 0.2683 * (pressure - 1013.25)
                   - 0.0086 * (humidity - 50.0))
            e += ppm * x / 1000.0
        e += rng.normal(0.0, 3.0) + rng.normal(0.0, noise_um, len(x))
        begin = START + pd.Timedelta(minutes=40 * k)
        frames.append(pd.DataFrame({
            "machine_id": "VMC-3", "axis": "Y", "test_id": f"t{k}-f{feed:g}-d{dwell:g}",
            "method": "linear", "target": x, "direction": np.where(d > 0, "+", "-"),
            "cycle": cycle, "deviation_um": np.round(e, 2), "visit": "1", "repeat": 1,
            "feed_mm_min": feed, "dwell_s": dwell, "machine_temp_c": np.round(machine, 3),
            "ambient_temp_c": np.round(ambient, 3), "pressure_hpa": np.round(pressure, 2),
            "humidity_pct": np.round(humidity, 2), "started_at": begin,
            "measured_at": begin + pd.to_timedelta(seconds, "s")}))
    return pd.concat(frames, ignore_index=True)
