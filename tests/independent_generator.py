"""A second scenario generator, written independently of the twin (it never imports
``models.physics``): its own ISO 230-2 cycles, measuring systems, noise and its own functional
form for every effect, so the discovery benchmark is not graded on the twin's own equations.

It reads the same scenario dicts (``models.discovery.benchmark.expand``): the design's
targets, feeds, dwells, methods, measuring system and noise, and which effects are hidden. The
amplitudes and shapes are its own:

=====================  ==================================================================
backlash               constant clearance 2.5 um (machine to machine x0.9-1.1)
lead_error_linear      12 um/m
backlash_position      wear falling linearly from the home end: +2.2 um at x = 0, 0 at the
                       far end (not a bump)
backlash_feed          square-root friction law: 0.07 um * sqrt(feed / (mm/min))
backlash_temperature   -0.45 um/K against the run's mean screw temperature
lead_error_periodic    sine with a 25 % second harmonic, 1.1 um, the design's pitch
lead_error_profile     S-shaped: 2.5 um * tanh((x - L/2) / (L/7)) minus its chord
thermal_expansion      12 um/(m K) from a fixed bearing at the far end, screw warming
                       linearly along the run
thermal_drift          linear drift in time, 1.6 um per 15 min of run (not exponential)
air_refraction         full Edlen sensitivities -0.95 ppm/K, +0.268 ppm/hPa, -0.009 ppm/%RH
abbe                   pitch angle of an arc sin(pi x / L), 20 urad at 120 mm offset
dwell_settling         hyperbolic settling d * 1.8 um / (1 + dwell / 1.2 s) (not exponential)
=====================  ==================================================================
"""

from __future__ import annotations

import numpy as np
import pandas as pd

START = pd.Timestamp("2026-03-02 08:00")


def targets(plan: dict, rng: np.random.Generator) -> np.ndarray:
    """Target positions [mm]: even spacing, or ISO-style irregular spacing (each interior
    target shifted by up to 30 % of the spacing, its own random offsets)."""
    start, stop = plan.get("start_mm", 0.0), plan.get("stop_mm", 350.0)
    n = int(plan.get("n_targets", 8))
    t = np.linspace(start, stop, n)
    if plan.get("irregular", False):
        spacing = (stop - start) / (n - 1)
        t[1:-1] += rng.uniform(-0.3, 0.3, n - 2) * spacing
    return np.round(t, 3)


def cycle_readings(method: str, t: np.ndarray, cycles: int) -> list[tuple]:
    """(target index, direction, cycle, follows a reversal) in reading order."""
    out = []
    for c in range(1, cycles + 1):
        if method == "linear":
            out += [(i, 1, c, i == 0) for i in range(len(t))]
            out += [(i, -1, c, i == len(t) - 1) for i in reversed(range(len(t)))]
        else:
            for i in range(len(t)):
                out += [(i, 1, c, True), (i, -1, c, True)]
    return out


def generate(scenario: dict) -> pd.DataFrame:
    """Readings (docs/data-contract.md columns) of one scenario, with this module's own physics."""
    rng = np.random.default_rng(10_000 + scenario["seed"])
    plan = scenario["plan"]
    hidden = set(scenario["hidden"])
    t = targets(plan, rng)
    length = float(t.max() - t.min())
    pitch = scenario["effects"].get("lead_error_periodic", {}).get("pitch_mm", 10.0)
    b_machine = 2.5 * rng.uniform(0.9, 1.1)
    frames = []
    runs = [(m, f, d) for m in plan.get("methods", ["linear"])
            for f in plan.get("feeds_mm_min", [500.0]) for d in plan.get("dwells_s", [3.0])]
    env = scenario["environment"]
    temp_spread = env.get("machine_temp_spread_k", 0.5)
    air_spread = (env.get("ambient_spread_k", 0.3), env.get("pressure_spread_hpa", 4.0),
                  env.get("humidity_spread_pct", 5.0))
    run_temp, run_air = {}, {}
    for key in sorted({(f, d) for _, f, d in runs}):  # paired tests share their conditions
        run_temp[key] = 21.0 + rng.normal(0, temp_spread)
        run_air[key] = (20.5 + rng.normal(0, air_spread[0]), 1013.0 + rng.normal(0, air_spread[1]),
                        45.0 + rng.normal(0, air_spread[2]))
    for k, (method, feed, dwell) in enumerate(runs):
        order = cycle_readings(method, t, int(plan.get("cycles", 5)))
        idx = np.array([o[0] for o in order])
        d = np.array([o[1] for o in order], float)
        cycle = np.array([o[2] for o in order])
        reversal = np.array([o[3] for o in order])
        x = t[idx]
        seconds = np.cumsum(np.full(len(x), dwell + 60.0 * length / max(len(t) - 1, 1) / feed))
        warm = 0.8 * (feed / 1000.0) * seconds / 1800.0 if env.get("warmup_k", 1.5) else 0 * x
        temp = run_temp[(feed, dwell)] + warm
        ambient, pressure, humidity = run_air[(feed, dwell)]
        b = b_machine + np.zeros(len(x))
        if "backlash_position" in hidden:
            b = b + 2.2 * (1 - (x - t.min()) / length)
        if "backlash_feed" in hidden:
            b = b + 0.07 * np.sqrt(feed)
        if "backlash_temperature" in hidden:
            b = b - 0.45 * (temp.mean() - 20.0)
        b = np.maximum(b, 0.0)
        seen = reversal if scenario["system"] == "direct" else np.ones(len(x), bool)
        e = -d * b / 2 * seen + 12.0 * x / 1000.0
        if "lead_error_periodic" in hidden:
            phase = 2 * np.pi * x / pitch
            e = e + 1.1 * (np.sin(phase + 0.4) + 0.25 * np.sin(2 * phase))
        if "lead_error_profile" in hidden:
            s = 2.5 * np.tanh((x - t.min() - length / 2) / (length / 7))
            chord = np.interp(x, [t.min(), t.max()], [s.min(), s.max()])
            e = e + s - chord
        if "thermal_expansion" in hidden:
            e = e + 12.0 * (temp - 20.0) * (x - t.max()) / 1000.0
        if "thermal_drift" in hidden:
            e = e + 1.6 * seconds / 900.0
        if "air_refraction" in hidden:
            ppm = (-0.95 * (ambient - 20.0) + 0.268 * (pressure - 1013.25)
                   - 0.009 * (humidity - 50.0))
            e = e + ppm * x / 1000.0
        if "abbe" in hidden:
            e = e + 120.0 * 20.0 * np.sin(np.pi * (x - t.min()) / length) / 1000.0
        if "dwell_settling" in hidden:
            e = e + d * 1.8 / (1.0 + dwell / 1.2)
        e = e + 4.0 + rng.normal(0.0, scenario["noise_um"], len(x))  # the laser's datum
        frames.append(pd.DataFrame({
            "machine_id": "IND-1", "axis": "X", "test_id": f"run{k:02d}-{method}",
            "method": method, "target": x, "direction": np.where(d > 0, "+", "-"),
            "cycle": cycle, "deviation_um": np.round(e, 2), "visit": "1", "repeat": 1,
            "feed_mm_min": feed,
            "dwell_s": dwell, "machine_temp_c": np.round(temp, 3),
            "ambient_temp_c": round(ambient, 3), "pressure_hpa": round(pressure, 2),
            "humidity_pct": round(humidity, 2),
            "started_at": START + pd.Timedelta(minutes=30 * k),
            "measured_at": START + pd.Timedelta(minutes=30 * k) + pd.to_timedelta(seconds, "s"),
        }))
    return pd.concat(frames, ignore_index=True)
