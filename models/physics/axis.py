"""The feed axis: commanded path -> table position through the play -> laser reading.

Lost motion is a play (dead-zone) operator on the commanded path, not a sign flip: the table
follows the motor only when the motor has taken up the clearance b, so a reversal shorter than
b moves nothing (``play``). What the laser then sees depends on the measuring system:

- ``indirect`` (rotary encoder on the motor): the control stops the motor on target, the table
  lags by b/2 against the approach, on every reading: ISO B_i = -b.
- ``direct`` (linear scale closing the loop): the loop drives the table itself onto target and
  lost motion is only transient: a reading taken on the move that reversed the axis still shows
  the clearance not yet taken up (-d b/2), later readings in the same direction do not. So the
  linear cycle shows it only at its turn-around targets and the pendulum cycle everywhere.

Position errors (lead, thermal, refraction, Abbe, settling) add to every reading; the machine
warms up along the run; the reading gets white noise and is rounded to the laser's resolution.
All tests sharing a path run at once: one numpy step per waypoint, vectorised over tests.
"""

from __future__ import annotations

import numpy as np

from models.physics import effects
from models.physics.cycles import Path

SYSTEMS = ("indirect", "direct")


def play(commanded_mm: np.ndarray, width_um: np.ndarray) -> np.ndarray:
    """Table positions [mm] for commanded motor positions [mm], shape (tests, waypoints):
    p_k = clip(p_(k-1), m_k - b_k/2, m_k + b_k/2), starting centred on the first waypoint."""
    half = width_um / 2000.0
    table = np.empty_like(commanded_mm)
    p = commanded_mm[:, 0].copy()
    for k in range(commanded_mm.shape[1]):
        p = np.clip(p, commanded_mm[:, k] - half[:, k], commanded_mm[:, k] + half[:, k])
        table[:, k] = p
    return table


def run_times_s(path: Path, feed_mm_min: np.ndarray, dwell_s: np.ndarray) -> np.ndarray:
    """Time since the run's start at each waypoint [s], readings taken at the end of the dwell,
    shape (tests, waypoints)."""
    travel = np.abs(np.diff(path.position_mm, prepend=path.position_mm[0]))
    seconds = travel[None, :] / feed_mm_min[:, None] * 60.0 + path.read[None, :] * dwell_s[:, None]
    return np.cumsum(seconds, axis=1)


def machine_temperature_c(start_c, warmup_k, tau_s, elapsed_s):
    """Screw temperature warming from its start value: T = T0 + dT (1 - exp(-t / tau))."""
    return start_c[:, None] + warmup_k[:, None] * (1 - np.exp(-elapsed_s / tau_s))


def simulate_tests(path: Path, targets_mm: np.ndarray, tests: dict, enabled: dict, system: str,
                   noise_um: float, resolution_um: float, rng: np.random.Generator,
                   compensation=None) -> dict:
    """Readings of every test on one path.

    ``tests``: arrays per test — feed_mm_min, dwell_s, machine_temp_start_c, warmup_k,
    warmup_tau_s, ambient_temp_c, pressure_hpa, humidity_pct, and ``params`` (dict of effect
    name -> dict of parameter arrays, per test). Returns arrays of shape (tests, readings):
    deviation_um, true_backlash_um, one ``effect:<name>`` entry per position effect, the
    conditions at each reading, and per-reading target, direction and cycle.

    ``compensation`` (optional): one controller model per test (or None), with
    ``motor_path(commanded_mm, direction)`` (``models.physics.controller.Compensation``); its
    offsets are added to the commanded path ahead of the play, as the controller does.
    """
    n = len(tests["feed_mm_min"])
    elapsed = run_times_s(path, tests["feed_mm_min"], tests["dwell_s"])
    conditions = {
        "feed_mm_min": np.repeat(tests["feed_mm_min"][:, None], len(path.position_mm), 1),
        "dwell_s": np.repeat(tests["dwell_s"][:, None], len(path.position_mm), 1),
        "machine_temp_c": machine_temperature_c(tests["machine_temp_start_c"], tests["warmup_k"],
                                                tests["warmup_tau_s"], elapsed),
        "elapsed_s": elapsed,
        **{k: np.repeat(tests[k][:, None], len(path.position_mm), 1)
           for k in ("ambient_temp_c", "pressure_hpa", "humidity_pct")},
    }
    position = np.broadcast_to(path.position_mm, (n, len(path.position_mm)))
    width = np.zeros((n, len(path.position_mm)))
    for name in effects.LOST_MOTION:
        if name in enabled:
            width += effects.contribution(name, position, 0, conditions,
                                          **_column(tests["params"][name]))
    width = np.maximum(width, 0.0)
    read = path.read
    target = targets_mm[path.target_index[read]]
    direction = path.direction[read]
    if system == "indirect" and compensation is not None:
        lost = (_compensated_table(path, compensation, width)[:, read] - position[:, read]) * 1000.0
    elif system == "indirect":
        lost = (play(position, width)[:, read] - position[:, read]) * 1000.0
    else:
        lost = -direction * width[:, read] / 2 * path.reversal[read]
        if compensation is not None:  # the scale loop drives the table onto setpoint + offset
            offsets = _compensated_motor(path, compensation)[:, 1::2] - position
            lost = lost + offsets[:, read] * 1000.0
    at_read = {k: v[:, read] for k, v in conditions.items()}
    out = {"true_backlash_um": width[:, read], "lost_motion_um": lost}
    deviation = lost.copy()
    for name, params in tests["params"].items():
        if name in effects.LOST_MOTION:
            continue
        part = effects.contribution(name, np.broadcast_to(target, lost.shape),
                                    np.broadcast_to(direction, lost.shape), at_read,
                                    **_column(params))
        out[f"effect:{name}"] = part
        deviation += part
    deviation += rng.normal(0.0, noise_um, deviation.shape)
    if resolution_um > 0:
        deviation = np.round(deviation / resolution_um) * resolution_um
    out.update(deviation_um=deviation, target=target, direction=direction,
               cycle=path.cycle[read], **at_read)
    return out


def _column(params: dict) -> dict:
    """Per-test parameter arrays as a column against the (tests, points) arrays."""
    return {k: (np.asarray(v)[:, None] if np.ndim(v) else v) for k, v in params.items()}


def _compensated_motor(path: Path, compensation) -> np.ndarray:
    """Motor path per test with each test's controller offsets, two points per move (start,
    end), shape (tests, 2 * waypoints); a test without a controller follows the plain path."""
    plain = np.repeat(path.position_mm, 2)
    plain[0::2] = np.r_[path.position_mm[0], path.position_mm[:-1]]
    cache = {}
    for c in compensation:
        if c is not None and id(c) not in cache:
            cache[id(c)] = c.motor_path(path.position_mm, path.direction)
    return np.stack([plain if c is None else cache[id(c)] for c in compensation])


def _compensated_table(path: Path, compensation, width: np.ndarray) -> np.ndarray:
    """Table positions [mm] at the waypoints when the motor follows the compensated path."""
    motor = _compensated_motor(path, compensation)
    before = np.c_[width[:, :1], width[:, :-1]]
    widths = np.stack([before, width], axis=2).reshape(motor.shape)
    return play(motor, widths)[:, 1::2]
