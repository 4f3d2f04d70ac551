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

Units: positions in mm and errors in um on a linear axis; on a rotary axis (a worm-driven
table) the same arrays hold degrees and arcsec, and ``per_unit`` (errors per position unit:
1000 um/mm, 3600 arcsec/deg) converts between them.
"""

from __future__ import annotations

import numpy as np

from models.physics import effects
from models.physics.cycles import Path

SYSTEMS = ("indirect", "direct")


def play(commanded_mm: np.ndarray, width_um: np.ndarray, per_unit=1000.0) -> np.ndarray:
    """Table positions [mm] for commanded motor positions [mm], shape (tests, waypoints):
    p_k = clip(p_(k-1), m_k - b_k/2, m_k + b_k/2), starting centred on the first waypoint.
    ``per_unit``: width units per position unit (1000 um/mm; 3600 arcsec/deg on a rotary
    axis), a scalar or one value per test (tests, 1)."""
    half = width_um / (2.0 * np.asarray(per_unit, float))
    # waypoint-major copies: each step of the sequential loop reads and writes one contiguous row
    low = np.ascontiguousarray((commanded_mm - half).T)
    high = np.ascontiguousarray((commanded_mm + half).T)
    table = np.empty_like(low)
    p = commanded_mm[:, 0].copy()
    for k in range(len(table)):
        p = np.clip(p, low[k], high[k], out=table[k])
    return table.T


def run_times_s(path: Path, feed_mm_min: np.ndarray, dwell_s: np.ndarray) -> np.ndarray:
    """Time since the run's start at each waypoint [s], readings taken at the end of the dwell,
    shape (tests, waypoints)."""
    travel = np.abs(np.diff(path.position_mm, prepend=path.position_mm[0]))
    seconds = travel[None, :] / feed_mm_min[:, None] * 60.0 + path.read[None, :] * dwell_s[:, None]
    return np.cumsum(seconds, axis=1)


def warmed_fraction(elapsed_s, tau_s):
    """Part of its warm-up the screw has reached after ``elapsed_s`` [s]: the screw warms from
    its start value T0 as T = T0 + dT (1 - exp(-t / tau)), t [s] time since the run's start, dT
    [K] the warm-up the run's feed drives towards, tau [s] the screw's thermal time constant."""
    return 1 - np.exp(-elapsed_s / tau_s)


def machine_temperature_c(start_c, warmup_k, tau_s, elapsed_s):
    """Screw temperature warming from its start value [degC], shape (tests, waypoints):
    T = T0 + dT (1 - exp(-t / tau)) (``warmed_fraction``)."""
    return start_c[:, None] + warmup_k[:, None] * warmed_fraction(elapsed_s, tau_s)


def machine_temperature_cooling_c(path: Path, feed_mm_min, dwell_s, start_c, warmup_k, tau_s,
                                  ambient_c, cooling_tau_s):
    """Screw temperature [degC] from a heat balance with the air, shape (tests, waypoints),
    read at the end of the dwell.

    Moving: dT/dt = (T_air + dT_warm - T) / tau, friction in nut and bearings holds the screw
    dT_warm [K] above the air; dwelling: dT/dt = (T_air - T) / tau_cool, the drive stands and the
    screw gives its heat to the air. Exact per segment: T <- T_eq + (T - T_eq) exp(-dt / tau),
    starting from T0 = ``start_c``. Sequential along the path, vectorised over tests.
    ``ambient_c`` (tests, waypoints) [degC]; ``warmup_k`` per test [K]; time constants [s]."""
    travel = np.abs(np.diff(path.position_mm, prepend=path.position_mm[0]))
    # waypoint-major copies: each step of the sequential loop works on contiguous rows
    keep_moving = np.exp(-travel[:, None] / feed_mm_min[None, :] * 60.0 / tau_s)
    ambient = np.ascontiguousarray(np.asarray(ambient_c).T)
    keep_dwell = np.exp(-dwell_s / cooling_tau_s)
    out = np.empty_like(keep_moving)
    t = np.asarray(start_c, float).copy()
    for k in range(len(out)):
        hot = ambient[k] + warmup_k
        t = hot + (t - hot) * keep_moving[k]
        if path.read[k]:
            t = ambient[k] + (t - ambient[k]) * keep_dwell
        out[k] = t
    return out.T


def simulate_tests(path: Path, targets_mm: np.ndarray, tests: dict, enabled: dict, system: str,
                   noise_um: float, resolution_um: float, rng: np.random.Generator,
                   compensation=None) -> dict:
    """Readings of every test on one path.

    ``tests``: arrays per test — feed_mm_min, dwell_s, machine_temp_start_c, warmup_k,
    warmup_tau_s, ambient_temp_c, pressure_hpa, humidity_pct, and ``params`` (dict of effect
    name -> dict of parameter arrays, per test); optional scalars ambient_drift_k_per_h,
    pressure_drift_hpa_per_h, humidity_drift_pct_per_h (air profiles along the run) and
    cooling_tau_s (> 0: the screw cools towards ambient during each dwell); optional
    wear_local_um (per test, peak of the local wear [um]) with scalars wear_center_mm and
    wear_width_mm: a worn zone of ``backlash_position``'s shape added to the play width;
    optional ``per_unit`` (per test, default 1000): error units per position unit, 3600 for a
    rotary axis (positions in deg, errors in arcsec).
    Returns arrays of shape (tests, readings): deviation_um, true_backlash_um, one ``effect:<name>`` entry per position effect, the
    conditions at each reading, and per-reading target, direction and cycle; the run times
    once per (feed, dwell) pair, ``pair_elapsed_s`` (pairs, readings), with each test's pair
    ``pair_of_test``: ``elapsed_s == pair_elapsed_s[pair_of_test]``.

    ``compensation`` (optional): one controller model per test (or None), with
    ``motor_path(commanded_mm, direction)`` (``models.physics.controller.Compensation``); its
    offsets are added to the commanded path ahead of the play, as the controller does.

    Every quantity is evaluated only where it is used: the play width along the whole path
    for an indirect system (the play operator runs along it), at the readings for a direct
    one; conditions and position errors at the readings. Each value is computed as if along
    the whole path: the numbers do not depend on it.
    """
    n = len(tests["feed_mm_min"])
    per_unit = np.broadcast_to(np.asarray(tests.get("per_unit", 1000.0), float), (n,))[:, None]
    read = np.flatnonzero(path.read)
    # waypoint columns where the play width is needed, and the readings among them
    at, to_read = ((np.arange(len(path.position_mm)), read) if system == "indirect"
                   else (read, slice(None)))
    clock = _Clock(path, tests["feed_mm_min"], tests["dwell_s"])
    conditions = _conditions(path, tests, clock, at)
    width = _play_width(path, tests, enabled, conditions, at)
    at_read = {k: v[:, to_read] for k, v in conditions.items()}
    target = targets_mm[path.target_index[read]]
    direction = path.direction[read]
    position = np.broadcast_to(path.position_mm, (n, len(path.position_mm)))
    if system == "indirect" and compensation is not None:
        table = _compensated_table(path, compensation, width, per_unit)
        lost = (table[:, read] - position[:, read]) * per_unit
    elif system == "indirect":
        lost = (play(position, width, per_unit)[:, read] - position[:, read]) * per_unit
    else:
        lost = -direction * width / 2 * path.reversal[read]
        if compensation is not None:  # the scale loop drives the table onto setpoint + offset
            offsets = _compensated_motor(path, compensation)[:, 1::2][:, read] - position[:, read]
            lost = lost + offsets * per_unit
    out = {"true_backlash_um": width[:, to_read], "lost_motion_um": lost}
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
    if resolution_um > 0:  # in place: round(deviation / resolution) * resolution
        np.divide(deviation, resolution_um, out=deviation)
        np.round(deviation, out=deviation)
        np.multiply(deviation, resolution_um, out=deviation)
    out.update(deviation_um=deviation, target=target, direction=direction,
               cycle=path.cycle[read], pair_elapsed_s=clock.seconds[:, read],
               pair_of_test=clock.of_test, **at_read)
    return out


class _Clock:
    """Time since the run's start [s] of every test at the waypoints. The tests of a block share
    a handful of (feed, dwell) pairs and a test's clock depends on nothing else: each pair's
    clock is computed once (``seconds``, pairs x waypoints) and ``of_test`` picks it per test."""

    def __init__(self, path: Path, feed_mm_min: np.ndarray, dwell_s: np.ndarray):
        pairs, inverse = np.unique(np.c_[feed_mm_min, dwell_s], axis=0, return_inverse=True)
        self.seconds = run_times_s(path, pairs[:, 0], pairs[:, 1])
        self.of_test = inverse.ravel()

    def at(self, columns) -> np.ndarray:
        """Elapsed time of every test at the waypoint ``columns``, shape (tests, columns)."""
        return self.seconds[:, columns][self.of_test]


def _conditions(path: Path, tests: dict, clock: _Clock, at) -> dict:
    """Conditions of every test at the waypoint columns ``at``, (tests, columns) arrays."""
    elapsed = clock.at(at)
    hours = elapsed / 3600.0
    # air profiles: the run's start value plus a linear drift along the run (drifts default 0)
    air = {k: tests[k][:, None] + tests.get(drift, 0.0) * hours for k, drift in (
        ("ambient_temp_c", "ambient_drift_k_per_h"), ("pressure_hpa", "pressure_drift_hpa_per_h"),
        ("humidity_pct", "humidity_drift_pct_per_h"))}
    if tests.get("cooling_tau_s", 0.0) > 0:  # a heat balance, sequential along the whole path
        ambient = (tests["ambient_temp_c"][:, None]
                   + tests.get("ambient_drift_k_per_h", 0.0) * (clock.at(slice(None)) / 3600.0))
        machine = machine_temperature_cooling_c(
            path, tests["feed_mm_min"], tests["dwell_s"], tests["machine_temp_start_c"],
            tests["warmup_k"], tests["warmup_tau_s"], ambient, tests["cooling_tau_s"])[:, at]
    else:  # machine_temperature_c, with the warm-up's shape once per (feed, dwell) pair
        warmed = warmed_fraction(clock.seconds[:, at], tests["warmup_tau_s"])[clock.of_test]
        machine = tests["machine_temp_start_c"][:, None] + tests["warmup_k"][:, None] * warmed
    return {"feed_mm_min": np.repeat(tests["feed_mm_min"][:, None], len(at), 1),
            "dwell_s": np.repeat(tests["dwell_s"][:, None], len(at), 1),
            "machine_temp_c": machine, "elapsed_s": elapsed, **air}


def _play_width(path: Path, tests: dict, enabled: dict, conditions: dict, at) -> np.ndarray:
    """Play width b [um] of every test at the waypoint columns ``at``: the enabled lost-motion
    effects and the local wear, never negative."""
    position = np.broadcast_to(path.position_mm[at], conditions["elapsed_s"].shape)
    width = np.zeros(position.shape)
    for name in effects.LOST_MOTION:
        if name in enabled:
            width += effects.contribution(name, position, 0, conditions,
                                          **_column(tests["params"][name]))
    if np.any(tests.get("wear_local_um", 0.0)):  # local wear: a worn zone growing with hours
        width += effects.contribution("backlash_position", position, 0, conditions,
                                      amplitude_um=np.asarray(tests["wear_local_um"])[:, None],
                                      center_mm=tests["wear_center_mm"],
                                      width_mm=tests["wear_width_mm"])
    return np.maximum(width, 0.0, out=width)


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


def _compensated_table(path: Path, compensation, width: np.ndarray, per_unit) -> np.ndarray:
    """Table positions [mm] at the waypoints when the motor follows the compensated path."""
    motor = _compensated_motor(path, compensation)
    before = np.c_[width[:, :1], width[:, :-1]]
    widths = np.stack([before, width], axis=2).reshape(motor.shape)
    return play(motor, widths, per_unit)[:, 1::2]
