"""Test campaigns of the twin: machines x axes x maintenance visits x test conditions.

A configuration (a preset name, a dict, or a TOML file of the same shape) says

```toml
system = "direct"                      # or "indirect"
[plan]                                  # the ISO 230-2 tests of one visit
targets_mm = [0, 50, 100, 150, 200, 250, 300, 350]   # or start_mm, stop_mm, n_targets
irregular = false                       # ISO irregular target spacing
feeds_mm_min = [200, 500, 1200]
dwells_s = [3, 5, 7]
repeats = 3
cycles = 5
methods = ["linear", "pendulum"]
overrun_mm = 5.0
[fleet]
machines = 1
axes = ["X"]
visits = 6
interval_days = 30
hours_per_day = 8.0                     # axis operating hours accumulate between visits
wear_um_per_1000h = 0.6                 # uniform lost-motion growth with operating hours
wear_local_um_per_1000h = 0.0           # extra growth where the axis works most (peak rate)
wear_center_mm = 175.0                  # centre of the worn zone
wear_width_mm = 60.0                    # its half-width (Gaussian, as backlash_position)
adjust_at = [4]                         # visits (1-based) at which a mechanic re-adjusted the nut
adjusted_b0_um = 1.2                    # b0 right after an adjustment
failure_at = 0                          # visit of a sudden failure (0: none)
failure_jump_um = 3.0
start = "2026-01-05"
[environment]
machine_temp_c = 21.0                   # start-of-run screw temperature
machine_temp_spread_k = 0.5             # its run-to-run spread (also ambient_spread_k,
                                        # pressure_spread_hpa, humidity_spread_pct)
warmup_k = 1.5                          # warm-up of the screw during a run at 1000 mm/min
warmup_tau_s = 1200.0                   # the screw's thermal time constant
cooling_tau_s = 0.0                     # > 0: heat balance with the air, cooling in dwells
ambient_drift_k_per_h = 0.0             # air profiles along a run (also pressure_drift_hpa_per_h,
                                        # humidity_drift_pct_per_h)
ambient_temp_c = 20.5
pressure_hpa = 1013.0
humidity_pct = 45.0
[noise]
noise_um = 0.3
resolution_um = 0.1
[effects.backlash]                      # enabled effects and their parameters
b0_um = 2.0
[effects.backlash_feed]
```

Wear: lost motion grows with operating hours h since the last adjustment at a rate that varies
along the screw, w(x) = wear_um_per_1000h + s * wear_local_um_per_1000h *
exp(-((x - wear_center_mm) / wear_width_mm)^2) [um per 1000 h], s the machine's factor
(0.8-1.25): the uniform part adds to ``backlash``'s b0, the local part is a ``backlash_position``
bump whose amplitude grows with h. An adjustment resets the hours (and so the wear) and sets b0
to ``adjusted_b0_um``; a failure adds ``failure_jump_um``. The visit table records the hours,
b0, the local wear's peak ``wear_local_um`` and rate ``wear_local_um_per_1000h``; the truth table
records ``wear_um`` (uniform plus local wear) at every target.
A rotary axis (A, B, C) reads every ``*_mm`` value as degrees, every ``*_um`` value as arcsec
and feeds as deg/min (the ``rotary`` preset: a worm-driven table over a full turn); one
campaign may mix linear and rotary axes.
The paper plan (``paper`` preset): 8 targets over 0-350 mm, feeds 200/500/1200 mm/min, dwells
3/5/7 s, 3 repeats, linear and pendulum, 5 cycles: 3 x 3 x 3 x 8 targets x 2 directions = 432
paired linear/pendulum points per axis (324 at interior targets, i.e. 162 backlash points).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from features.readings import schema
from features.readings.config import as_table, from_table, read_config
from features.readings.errors import InputError
from features.readings.validation import PLAUSIBLE
from models.physics import PRESETS, effects
from models.physics.axis import SYSTEMS, simulate_tests
from models.physics.cycles import path, target_positions


# --------------------------------------------------------------------------- the configuration
@dataclass
class Plan:
    """The ISO 230-2 tests of one visit: targets [mm], feeds [mm/min], dwells [s], repeats
    of each condition, cycles per test, methods and the overrun beyond the end targets [mm].
    ``targets_mm`` (explicit targets) wins over ``start_mm``/``stop_mm``/``n_targets``."""

    targets_mm: list[float] | None = None
    start_mm: float = 0.0
    stop_mm: float = 350.0
    n_targets: int = 8
    irregular: bool = False
    feeds_mm_min: list[float] = field(default_factory=lambda: [200.0, 500.0, 1200.0])
    dwells_s: list[float] = field(default_factory=lambda: [3.0, 5.0, 7.0])
    repeats: int = 3
    cycles: int = 5
    methods: list[str] = field(default_factory=lambda: ["linear", "pendulum"])
    overrun_mm: float = 5.0


@dataclass
class Fleet:
    """Machines, axes and maintenance visits: the calendar [days], the use between visits
    [h/day], wear rates [um per 1000 h] and the worn zone [mm], adjustments and a failure."""

    machines: int = 1
    axes: list[str] = field(default_factory=lambda: ["X"])
    visits: int = 1
    interval_days: float = 30
    hours_per_day: float = 8.0
    wear_um_per_1000h: float = 0.6
    wear_local_um_per_1000h: float = 0.0
    wear_center_mm: float = 175.0
    wear_width_mm: float = 60.0
    adjust_at: list[int] = field(default_factory=list)
    adjusted_b0_um: float = 1.2
    failure_at: int = 0
    failure_jump_um: float = 3.0
    start: str = "2026-01-05"


@dataclass
class Environment:
    """Run conditions: start values, their run-to-run spread (standard deviations) and their
    profiles along a run (the air's linear drifts, the screw's warm-up and cooling)."""

    machine_temp_c: float = 21.0
    warmup_k: float = 1.5
    warmup_tau_s: float = 1200.0
    ambient_temp_c: float = 20.5
    pressure_hpa: float = 1013.0
    humidity_pct: float = 45.0
    machine_temp_spread_k: float = 0.5
    ambient_spread_k: float = 0.3
    pressure_spread_hpa: float = 4.0
    humidity_spread_pct: float = 5.0
    ambient_drift_k_per_h: float = 0.0
    pressure_drift_hpa_per_h: float = 0.0
    humidity_drift_pct_per_h: float = 0.0
    cooling_tau_s: float = 0.0  # 0: no cooling towards the air during dwells


@dataclass
class Noise:
    """The laser's reading noise (standard deviation) and resolution [um]."""

    noise_um: float = 0.3
    resolution_um: float = 0.1


def _default_effects() -> dict:
    return {"backlash": {"b0_um": 1.5}, "backlash_position": {"amplitude_um": 0.6},
            "backlash_feed": {"k_um_per_m_min": 1.2},
            "backlash_temperature": {"k_um_per_k": -0.3},
            "lead_error_linear": {}, "thermal_expansion": {}}


@dataclass
class Campaign:
    """A whole twin campaign (see the module docstring for the file)."""

    system: Literal["indirect", "direct"] = "direct"
    plan: Plan = field(default_factory=Plan)
    fleet: Fleet = field(default_factory=Fleet)
    environment: Environment = field(default_factory=Environment)
    noise: Noise = field(default_factory=Noise)
    # enabled effects and their parameters; a file's [effects] replaces the preset's whole
    effects: dict[str, dict[str, float]] = field(default_factory=_default_effects)

    def check(self, file) -> None:
        """Refuse what no test campaign can be (one ``InputError`` naming the key)."""
        _check(self, file)


@dataclass
class Simulation:
    readings: pd.DataFrame
    truth: pd.DataFrame
    visits: pd.DataFrame
    parameters: dict = field(default_factory=dict)


def load_config(source=None, preset: str | None = None) -> Campaign:
    """A full, checked campaign.

    Parameters
    ----------
    source : str, Path, dict or Campaign, optional
        A preset name, a campaign TOML file, a dict of the same shape, or a campaign (returned
        as it is). Its values apply on top of ``preset``.
    preset : str, optional
        The preset the source overrides (default: the built-in defaults).

    Raises
    ------
    InputError
        An unknown preset (``parameter="preset"``), or a key or value the campaign cannot have
        (naming the file and the key's dotted path).
    """
    if isinstance(source, Campaign):
        return copy.deepcopy(source)
    if preset is not None and preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}; expected one of {', '.join(PRESETS)}",
                         parameter="preset")
    base = read_config(PRESETS[preset], Campaign, what="preset") if preset else None
    if source is None:
        return base if base is not None else Campaign()
    if isinstance(source, (str, Path)) and str(source) in PRESETS:
        return read_config(PRESETS[str(source)], Campaign, base=base, what="preset")
    if isinstance(source, dict):
        return from_table(source, Campaign, base=base, file="config")
    return read_config(source, Campaign, base=base, what="config")


# Readings of one simulation held in memory at once [bytes per reading], readings and truth
# frames with their intermediate arrays (measured on the fleet benchmark)
BYTES_PER_READING = 150


def _check(config: Campaign, where) -> None:
    def bad(column, message):
        raise InputError(message, file=where, column=column)

    plan, fleet, env = config.plan, config.fleet, config.environment
    for name, params in config.effects.items():
        if name not in effects.EFFECTS:
            bad(f"effects.{name}", f"unknown effect {name!r}; expected one of "
                                   f"{', '.join(effects.EFFECTS)}")
        unknown = set(params) - set(effects.DEFAULTS[name])
        if unknown:
            bad(f"effects.{name}", f"unknown parameter {min(unknown)!r} of {name}; expected "
                                   f"{', '.join(effects.DEFAULTS[name]) or 'none'}")
    _check_counts(config, bad)
    _check_size(config, where)
    if config.system not in SYSTEMS:
        bad("system", f"expected one of {', '.join(SYSTEMS)}, got {config.system!r}")
    if plan.targets_mm is not None and len(plan.targets_mm) == 0:
        bad("plan.targets_mm", "empty target list: a test needs at least 2 targets")
    if len(_targets(plan)) < 2:
        bad("plan", "a test needs at least 2 targets")
    if plan.targets_mm is None and plan.stop_mm <= plan.start_mm:
        bad("plan.stop_mm", f"the targets run from start_mm to stop_mm: stop_mm "
                            f"({plan.stop_mm:g}) must be above start_mm ({plan.start_mm:g})")
    if not plan.feeds_mm_min or min(plan.feeds_mm_min) <= 0:
        bad("plan.feeds_mm_min", "every feed must be > 0 mm/min")
    if not plan.dwells_s or min(plan.dwells_s) < 0:
        bad("plan.dwells_s", "every dwell must be >= 0 s")
    if plan.cycles < 2:
        bad("plan.cycles", "ISO 230-2 needs at least 2 cycles")
    if plan.overrun_mm < 0:
        bad("plan.overrun_mm", f"the overrun is a distance >= 0 mm, got {plan.overrun_mm:g}")
    if set(plan.methods) - {"linear", "pendulum"} or not plan.methods:
        bad("plan.methods", "expected a list of 'linear' and/or 'pendulum'")
    # the rules of the readings the campaign will write
    axes = (*schema.LINEAR_AXES, *schema.ROTARY_AXES)
    unknown = [a for a in fleet.axes if a not in axes]
    if unknown or not fleet.axes:
        bad("fleet.axes", f"unknown axis {unknown[0] if unknown else ''!r}; expected some of "
                          f"{', '.join(axes)}")
    for column, values in (("plan.targets_mm", plan.targets_mm or []),
                           ("plan.feeds_mm_min", plan.feeds_mm_min),
                           ("plan.dwells_s", plan.dwells_s), ("plan.methods", plan.methods),
                           ("fleet.axes", fleet.axes)):
        doubled = sorted({str(v) for v in values if list(values).count(v) > 1})
        if doubled:
            bad(column, f"{doubled[0]} given twice; every test and target must be unique")
    for column, values in (("plan.feeds_mm_min", plan.feeds_mm_min),
                           ("plan.dwells_s", plan.dwells_s)):
        low, high, expected = PLAUSIBLE[column.split(".")[1].replace("feeds", "feed")
                                        .replace("dwells", "dwell")]
        if any(v > high for v in values):
            bad(column, f"{max(values):g} is not {expected}")
    for name in ("machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct"):
        low, high, expected = PLAUSIBLE[name]
        if not low <= getattr(env, name) <= high:
            bad(f"environment.{name}", f"{getattr(env, name):g} is not {expected}")
    try:
        pd.Timestamp(fleet.start)
    except ValueError:
        bad("fleet.start", f"{fleet.start!r} is not an ISO 8601 date")
    for column, value in (("effects.backlash.b0_um", config.effects.get("backlash", {})
                           .get("b0_um", 0.0)), ("fleet.adjusted_b0_um", fleet.adjusted_b0_um),
                          ("fleet.wear_um_per_1000h", fleet.wear_um_per_1000h),
                          ("fleet.wear_local_um_per_1000h", fleet.wear_local_um_per_1000h)):
        if value < 0:
            bad(column, f"negative backlash ({value}); lost motion is a clearance >= 0 um")
    if fleet.wear_width_mm <= 0:
        bad("fleet.wear_width_mm", "the worn zone's width must be > 0 mm")
    for key in ("warmup_tau_s", "cooling_tau_s"):
        if getattr(env, key) < 0 or (key == "warmup_tau_s" and env.warmup_tau_s == 0):
            bad(f"environment.{key}", "a thermal time constant must be > 0 s")
    for key in ("machine_temp_spread_k", "ambient_spread_k", "pressure_spread_hpa",
                "humidity_spread_pct"):
        if getattr(env, key) < 0:
            bad(f"environment.{key}", f"a spread is a standard deviation >= 0, got "
                                      f"{getattr(env, key):g}")
    if config.noise.noise_um < 0 or config.noise.resolution_um < 0:
        bad("noise", "noise and resolution must be >= 0")


def _check_counts(config: Campaign, bad) -> None:
    """Counts, durations and calendar values that no campaign can have."""
    plan, fleet = config.plan, config.fleet
    for column, value in (("fleet.machines", fleet.machines), ("fleet.visits", fleet.visits),
                          ("plan.repeats", plan.repeats), ("plan.n_targets", plan.n_targets)):
        if value < 1:
            bad(column, f"must be at least 1, got {value}")
    if fleet.interval_days < 0:
        bad("fleet.interval_days", f"the time between visits is a duration >= 0 days, got "
                                   f"{fleet.interval_days:g}")
    if not 0 <= fleet.hours_per_day <= 24:
        bad("fleet.hours_per_day", f"an axis runs 0-24 h a day, got {fleet.hours_per_day:g}")
    if fleet.failure_jump_um < 0:
        bad("fleet.failure_jump_um", f"a failure adds lost motion (>= 0 um), got "
                                     f"{fleet.failure_jump_um:g}")
    if any(v < 1 for v in fleet.adjust_at):
        bad("fleet.adjust_at", f"visits count from 1, got {min(fleet.adjust_at)}")
    if fleet.failure_at < 0:
        bad("fleet.failure_at", f"visits count from 1 (0: no failure), got {fleet.failure_at}")


def n_readings(config) -> int:
    """Readings the campaign will write: machines x axes x visits x methods x feeds x dwells x
    repeats x cycles x 2 directions x targets."""
    config = load_config(config) if not isinstance(config, Campaign) else config
    plan, fleet = config.plan, config.fleet
    n_targets = len(plan.targets_mm) if plan.targets_mm is not None else plan.n_targets
    return int(np.prod([fleet.machines, len(fleet.axes), fleet.visits, len(plan.methods),
                        len(plan.feeds_mm_min), len(plan.dwells_s), plan.repeats, plan.cycles,
                        2, n_targets], dtype=float))


def available_memory_bytes() -> float:
    """Memory the machine can give now without swapping [bytes] (psutil's ``available``)."""
    import psutil

    return float(psutil.virtual_memory().available)


def _check_size(config: Campaign, where) -> None:
    """Refuse up front a campaign that cannot fit in memory, before anything is computed."""
    need = n_readings(config) * BYTES_PER_READING
    have = available_memory_bytes()
    if need > have:
        raise InputError(f"{n_readings(config):,} readings need about {need / 1e9:,.1f} GB, "
                         f"more than the {have / 1e9:.1f} GB of memory available; simulate fewer "
                         "machines, visits or conditions per run", file=where, column="fleet")


def _targets(plan: Plan) -> np.ndarray:
    if plan.targets_mm is not None:
        return np.asarray(plan.targets_mm, float)
    return target_positions(plan.start_mm, plan.stop_mm, plan.n_targets, plan.irregular)


def visit_table(config, rng: np.random.Generator) -> pd.DataFrame:
    """One row per machine, axis and visit: date, operating hours, b0 and the event."""
    config = load_config(config)
    fleet = config.fleet
    b0_nominal = config.effects.get("backlash", {}).get("b0_um", 0.0)
    rows = []
    for m in range(fleet.machines):
        for axis in fleet.axes:
            scale = rng.uniform(0.8, 1.25)  # machines and axes differ
            hours, b0, jump = 0.0, b0_nominal * scale, 0.0
            for v in range(1, fleet.visits + 1):
                event = ""
                if v > 1:
                    hours += fleet.hours_per_day * fleet.interval_days
                if v in fleet.adjust_at:
                    hours, b0, jump, event = 0.0, fleet.adjusted_b0_um * scale, 0.0, "adjustment"
                if v == fleet.failure_at:
                    jump, event = fleet.failure_jump_um, "failure"
                local_rate = fleet.wear_local_um_per_1000h * scale
                rows.append({
                    "machine_id": f"M{m + 1:02d}", "axis": axis, "visit": f"{v:02d}",
                    "started_at": pd.Timestamp(fleet.start)
                    + pd.Timedelta(days=(v - 1) * fleet.interval_days, hours=8),
                    "operating_hours": hours,
                    "b0_um": b0 + fleet.wear_um_per_1000h * hours / 1000 + jump,
                    "wear_local_um_per_1000h": local_rate,
                    "wear_local_um": local_rate * hours / 1000,
                    "event": event})
    return pd.DataFrame(rows)


def _fleet(fleet) -> Fleet:
    """A ``Fleet``, also from its table (``parameters.json``'s ``config.fleet``)."""
    return fleet if isinstance(fleet, Fleet) else from_table(fleet, Fleet, prefix="fleet.")


def wear_rate_um_per_1000h(position_mm, fleet, local_um_per_1000h=None) -> np.ndarray:
    """True wear-rate map [um per 1000 h] along the screw:
    w(x) = uniform + local exp(-((x - c) / width)^2), ``local`` the machine's peak rate
    (default the configured one). ``fleet`` is a ``Fleet`` or its table."""
    fleet = _fleet(fleet)
    local = fleet.wear_local_um_per_1000h if local_um_per_1000h is None else local_um_per_1000h
    bump = effects.contribution("backlash_position", np.asarray(position_mm, float), 0, {},
                                amplitude_um=1.0, center_mm=fleet.wear_center_mm,
                                width_mm=fleet.wear_width_mm)
    return fleet.wear_um_per_1000h + np.asarray(local, float) * bump


def local_wear_um(position_mm, fleet, peak_um) -> np.ndarray:
    """Local wear [um] at the positions for the given peak (the Gaussian worn zone)."""
    fleet = _fleet(fleet)
    return np.asarray(peak_um, float) * effects.contribution(
        "backlash_position", np.asarray(position_mm, float), 0, {}, amplitude_um=1.0,
        center_mm=fleet.wear_center_mm, width_mm=fleet.wear_width_mm)


def reference_backlash_um(config, b0_um: np.ndarray, wear_local_um=0.0) -> np.ndarray:
    """True lost motion of each visit at reference conditions [um]: the play width b summed over
    the enabled lost-motion effects with ``backlash``'s b0 of the visit and its local wear, the
    screw at 20 degC, the plan's median feed, averaged over the plan's targets (b >= 0 at each
    target)."""
    config = load_config(config)
    targets = _targets(config.plan)
    shape = (len(b0_um), len(targets))
    conditions = {"feed_mm_min": np.full(shape, float(np.median(config.plan.feeds_mm_min))),
                  "machine_temp_c": np.full(shape, effects.REFERENCE_TEMP_C)}
    width = np.zeros(shape)
    for name in effects.LOST_MOTION:
        if name in config.effects:
            params = dict(config.effects[name])
            if name == "backlash":
                params["b0_um"] = np.asarray(b0_um, float)[:, None]
            width += effects.contribution(name, np.broadcast_to(targets, shape), 0, conditions,
                                          **params)
    width += local_wear_um(np.broadcast_to(targets, shape), config.fleet,
                           np.broadcast_to(np.asarray(wear_local_um, float), len(b0_um))[:, None])
    return np.maximum(width, 0.0).mean(axis=1)


def simulate(config, seed: int = 0, compensation: dict | None = None,
             session_seed: int | None = None) -> Simulation:
    """Readings and truth of a whole campaign; same config and seed give the same numbers.
    ``compensation`` maps (machine_id, axis) to a controller model applied to its commanded
    path (``models.physics.controller``); the random draws do not depend on it.
    ``session_seed`` re-measures the same machines (same seed) in a new session: new run
    conditions and noise."""
    config = load_config(config)
    rng = np.random.default_rng(seed)
    plan = config.plan
    visits = visit_table(config, rng)
    visits.insert(len(visits.columns) - 1, "reference_backlash_um",
                  reference_backlash_um(config, visits["b0_um"].to_numpy(float),
                                        visits["wear_local_um"].to_numpy(float)))
    if session_seed is not None:
        rng = np.random.default_rng([seed, session_seed])
    targets = _targets(plan)
    tests = _test_table(config, visits, rng)
    # Names as codes: a fleet's readings repeat a few labels millions of times.
    readings, truth = _tables(tests, plan, targets)
    methods = readings.codes["method"]
    # from here on the tests are arrays of the values the blocks use (their labels are codes in
    # the tables), copied out so the frame goes
    tests = {c: tests[c].to_numpy(copy=True) for c in TEST_VALUES}
    # The truth's means are small matrix products, one per block and column: waking a second
    # BLAS thread for each costs more than it saves, and the thread count changes no number.
    with threadpool_limits(limits=1, user_api="blas"):
        for method in pd.unique(methods):  # in the order of the plan
            values = _simulate_method(config, readings.labels["method"][method], tests,
                                      np.flatnonzero(methods == method), targets, compensation,
                                      rng, readings, truth)
    readings = readings.frame(READING_ORDER)
    truth = truth.frame((*KEYS, "target", "direction", *values))
    parameters = {"config": as_table(config), "seed": seed, "targets_mm": targets.tolist(),
                  "reference_conditions": {
                      "machine_temp_c": effects.REFERENCE_TEMP_C,
                      "feed_mm_min": float(np.median(plan.feeds_mm_min)),
                      "ambient_temp_c": effects.REFERENCE_TEMP_C,
                      "pressure_hpa": effects.REFERENCE_PRESSURE_HPA,
                      "humidity_pct": effects.REFERENCE_HUMIDITY_PCT}}
    return Simulation(readings, truth, visits, parameters)


def _test_table(config: Campaign, visits: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """One row per test: its visit, method, feed, dwell and repeat, its id and start, and its
    run conditions (drawn from ``rng``). The index is the test's position (0, 1, ...)."""
    plan, env = config.plan, config.environment
    grid = pd.MultiIndex.from_product(
        [range(len(visits)), plan.methods, plan.feeds_mm_min, plan.dwells_s,
         range(1, plan.repeats + 1)],
        names=["v", "method", "feed_mm_min", "dwell_s", "repeat"]).to_frame(index=False)
    tests = grid.join(visits, on="v")
    tests["test_id"] = (tests["machine_id"] + "-" + tests["axis"] + "-v" + tests["visit"] + "-"
                        + tests["method"].str[:3] + "-f" + _formatted(tests["feed_mm_min"])
                        + "-d" + _formatted(tests["dwell_s"]) + "-r"
                        + tests["repeat"].astype(str))
    order = np.arange(len(tests)) % (len(tests) // len(visits))
    tests["started_at"] = tests["started_at"] + pd.to_timedelta(order * 20, unit="min")
    n = len(tests)
    tests["machine_temp_start_c"] = env.machine_temp_c + rng.normal(0, env.machine_temp_spread_k,
                                                                     n)
    tests["warmup_k"] = env.warmup_k * tests["feed_mm_min"] / 1000.0
    tests["ambient_temp_c"] = env.ambient_temp_c + rng.normal(0, env.ambient_spread_k, n)
    tests["pressure_hpa"] = env.pressure_hpa + rng.normal(0, env.pressure_spread_hpa, n)
    tests["humidity_pct"] = np.clip(env.humidity_pct + rng.normal(0, env.humidity_spread_pct, n),
                                    5, 95)
    return tests


def _formatted(values: pd.Series) -> pd.Series:
    """``{:g}`` text of each value, formatted once per distinct value."""
    return values.map({v: f"{v:g}" for v in values.unique()})


def _simulate_method(config: Campaign, method: str, tests: dict, positions: np.ndarray,
                     targets: np.ndarray, compensation, rng: np.random.Generator,
                     readings: _Table, truth: _Table) -> list[str]:
    """The tests of one method (at ``positions`` in the per-test arrays ``tests``) through
    their shared path, block after block, into the readings and truth tables; returns the
    truth's value columns."""
    plan, env = config.plan, config.environment
    p = path(method, targets, plan.cycles, float(plan.overrun_mm))
    grouping = _truth_groups(targets[p.target_index[p.read]], p.direction[p.read])
    axes = readings.labels["axis"]
    scale = np.array([schema.deviation_scale(a) for a in axes])  # per axis label
    scalars = {key: float(getattr(env, key)) for key in (
        "warmup_tau_s", "ambient_drift_k_per_h", "pressure_drift_hpa_per_h",
        "humidity_drift_pct_per_h", "cooling_tau_s")}
    scalars["wear_center_mm"] = float(config.fleet.wear_center_mm)
    scalars["wear_width_mm"] = float(config.fleet.wear_width_mm)
    # bounded blocks of tests keep the (tests x waypoints) arrays small; the noise is drawn
    # block after block from one generator, so the numbers do not depend on the block size
    for start in range(0, len(positions), CHUNK_TESTS):
        rows = positions[start:start + CHUNK_TESTS]
        block = {c: tests[c][rows].astype(float) for c in
                 ("feed_mm_min", "dwell_s", "machine_temp_start_c", "warmup_k",
                  "ambient_temp_c", "pressure_hpa", "humidity_pct", "wear_local_um")}
        block["per_unit"] = scale[readings.codes["axis"][rows]]
        block.update(scalars)
        block["params"] = {name: dict(values) for name, values in config.effects.items()}
        if "backlash" in block["params"]:
            block["params"]["backlash"]["b0_um"] = tests["b0_um"][rows].astype(float)
        comp = None if compensation is None else [
            compensation.get((readings.labels["machine_id"][m], axes[a])) for m, a in
            zip(readings.codes["machine_id"][rows], readings.codes["axis"][rows])]
        out = simulate_tests(p, targets, block, config.effects, config.system,
                             config.noise.noise_um, config.noise.resolution_um,
                             rng, compensation=comp)
        _add_readings(readings, tests, rows, out)
        values = _add_truth(truth, tests, rows, out, grouping, config)
        del out
    return values


CHUNK_TESTS = 2048
# per-test values the blocks of tests use
TEST_VALUES = ("feed_mm_min", "dwell_s", "repeat", "started_at", "operating_hours", "b0_um",
               "wear_local_um", "machine_temp_start_c", "warmup_k", "ambient_temp_c",
               "pressure_hpa", "humidity_pct")
KEYS = ("machine_id", "axis", "visit", "test_id", "method", "feed_mm_min", "dwell_s", "repeat")
# Labels held as categories. ``visit`` stays text: visits are compared by order
# (``readings["visit"] < "08"``), which unordered categories refuse.
LABELS = ("machine_id", "axis", "test_id", "method")
ENVIRONMENT = ("machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct")
# Narrow types where they lose nothing: cycle and repeat counts are small whole numbers, the
# environment is written to 3 decimals and the truth's contributions are means of noise-free
# physics in um (float32 keeps 7 significant digits). They halve a fleet's memory; arithmetic
# with them promotes to float64 / int64 as usual.
SMALL = {"repeat": np.int16, "cycle": np.int16, "environment": np.float32,
         "truth": np.float32}


class _Table:
    """A frame's columns allocated once at their final length and filled block of tests after
    block, so a fleet's rows are never held twice (as blocks and as their concatenation).
    Label columns hold codes into their ``labels`` until ``frame``: categories for those in
    ``categorical``, Arrow text for the others.

    A block is ``rows`` rows for each of its tests (``start``); ``put`` writes a block's values
    straight into the columns, broadcast against (tests, rows): a value per test as a column
    (tests, 1), a value per row of the test as a row (rows,), so no repeated or tiled copy of
    either is ever made."""

    def __init__(self, n_rows: int, labels: dict, codes: dict, categorical):
        self.n, self.at, self.labels = n_rows, 0, labels
        self.codes = codes  # per label column, every test's code (by the test's position)
        self.categorical = set(categorical)
        self.columns: dict[str, np.ndarray] = {}
        self.text: dict[str, list] = {}  # Arrow chunks of the text label columns
        self.shape = (0, 0)

    def start(self, n_tests: int, rows: int) -> None:
        """Begin a block of ``n_tests`` tests, ``rows`` rows each."""
        self.shape = (n_tests, rows)

    def end(self) -> None:
        """Move past the block just written."""
        self.at += self.shape[0] * self.shape[1]

    def put(self, name: str, values, dtype=None) -> None:
        values = np.asarray(values)
        if name not in self.columns:
            self.columns[name] = np.empty(self.n, dtype or values.dtype)
        size = self.shape[0] * self.shape[1]
        self.columns[name][self.at:self.at + size].reshape(self.shape)[...] = values

    def put_tests(self, tests: dict, rows: np.ndarray, columns) -> None:
        """Columns of the block's tests (``rows`` of the per-test arrays ``tests`` and of the
        label codes), each test's value on each of its rows."""
        import pyarrow as pa

        for column in columns:
            values = (self.codes if column in self.codes else tests)[column][rows]
            if column in self.labels and column not in self.categorical:
                # Arrow text, block by block: never a Python string per row
                values = np.repeat(values, self.shape[1])
                self.text.setdefault(column, []).append(pa.DictionaryArray.from_arrays(
                    values, pa.array(self.labels[column].to_numpy(str))).cast(pa.large_string()))
            else:
                self.put(column, values[:, None], SMALL.get(column, values.dtype))

    def frame(self, order) -> pd.DataFrame:
        import pyarrow as pa

        columns = {}
        for name in order:
            if name in self.text:  # pandas' own text type: large_string, taken without a copy
                values = pd.Series(pa.chunked_array(self.text.pop(name)).to_pandas(),
                                   copy=False)
            else:
                values = self.columns.pop(name)
            if name in self.categorical:
                values = pd.Categorical.from_codes(values, self.labels[name])
            columns[name] = values
        return pd.DataFrame(columns, copy=False)


def _tables(tests: pd.DataFrame, plan: Plan, targets: np.ndarray) -> tuple[_Table, _Table]:
    """Empty readings and truth tables of the right length: per test, its path's readings
    and its (target, direction) pairs."""
    reads, pairs = {}, {}
    for method in plan.methods:
        p = path(method, targets, plan.cycles, float(plan.overrun_mm))
        reads[method] = int(p.read.sum())
        pairs[method] = len(set(zip(p.target_index[p.read], p.direction[p.read])))
    labels, codes = {}, {}
    for c in (*LABELS, "visit"):  # sorted labels and every test's code into them, in one pass
        found, labels[c] = pd.factorize(tests[c], sort=True)
        codes[c] = found.astype(np.min_scalar_type(-len(labels[c])))
    labels["direction"] = pd.Index(["+", "-"])
    categorical = (*LABELS, "direction")
    method = tests["method"].astype(str)
    return (_Table(int(method.map(reads).sum()), labels, codes, categorical),
            _Table(int(method.map(pairs).sum()), labels, codes, categorical))


READING_ORDER = (*KEYS, "started_at", "operating_hours", "target", "direction", "cycle",
                 "deviation_um", "measured_at", *ENVIRONMENT)


def _add_readings(table: _Table, tests: dict, rows: np.ndarray, out: dict) -> None:
    table.start(*out["deviation_um"].shape)
    table.put_tests(tests, rows, (*KEYS, "started_at", "operating_hours"))
    table.put("target", out["target"], float)
    table.put("direction", out["direction"] < 0, np.int8)  # codes of +, -
    table.put("cycle", out["cycle"], SMALL["cycle"])
    table.put("deviation_um", out["deviation_um"], float)
    # run times in whole nanoseconds as pandas rounds them, once per (feed, dwell) pair rather
    # than per reading; the start plus the run time as pandas adds them
    pairs = out["pair_elapsed_s"]
    elapsed = pd.to_timedelta(pairs.ravel(), "s").to_numpy().reshape(pairs.shape)
    started = tests["started_at"][rows].astype("datetime64[ns]")
    table.put("measured_at", started[:, None] + elapsed[out["pair_of_test"]], "datetime64[ns]")
    for column in ENVIRONMENT:
        table.put(column, np.round(out[column], 3), SMALL["environment"])
    table.end()


def _truth_groups(target: np.ndarray, direction: np.ndarray) -> tuple[pd.MultiIndex, np.ndarray]:
    """The (target, direction) pairs of a path's readings in order of appearance, and the
    matrix that averages the readings over the cycles of each pair (readings, pairs)."""
    codes, groups = pd.factorize(pd.MultiIndex.from_arrays([target, direction]))
    onehot = np.zeros((len(codes), len(groups)))
    onehot[np.arange(len(codes)), codes] = 1.0
    onehot /= onehot.sum(axis=0)  # column means over the cycles
    return groups, onehot


def _add_truth(table: _Table, tests: dict, rows: np.ndarray, out: dict, grouping: tuple,
               config: Campaign) -> list[str]:
    """Mean over cycles per test, target and direction of the true lost motion and of every
    effect's contribution [um], and the wear (uniform plus local) at the target [um]; returns
    the names of the value columns. ``grouping``: the path's ``_truth_groups``."""
    groups, onehot = grouping
    table.start(len(rows), len(groups))
    table.put_tests(tests, rows, KEYS)
    target = groups.get_level_values(0).to_numpy(float)
    table.put("target", target)
    table.put("direction", groups.get_level_values(1).to_numpy() < 0, np.int8)
    columns = {"true_backlash_um": "true_backlash_um", "lost_motion_um": "lost_motion_um",
               **{k: k.removeprefix("effect:") + "_um" for k in out if k.startswith("effect:")}}
    for key_name, column in columns.items():
        table.put(column, out[key_name] @ onehot, SMALL["truth"])
    fleet = config.fleet
    hours = tests["operating_hours"][rows].astype(float)[:, None]
    peak = tests["wear_local_um"][rows].astype(float)[:, None]
    table.put("wear_um", fleet.wear_um_per_1000h * hours / 1000
              + local_wear_um(target, fleet, peak), float)
    table.end()
    return [*columns.values(), "wear_um"]


def paper_table(readings: pd.DataFrame) -> pd.DataFrame:
    """The backlash paper's Table 2 view: one row per target and condition with linear and
    pendulum mean deviations forward and reverse [mm], speed and environment."""
    keys = ["machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target"]
    means = (readings.groupby([*keys, "method", "direction"])["deviation_um"].mean() / 1000.0)
    wide = means.unstack(["method", "direction"])
    wide.columns = [f"dev_{'lin' if m == 'linear' else 'pend'}_{'f' if d == '+' else 'r'}_mm"
                    for m, d in wide.columns]
    env = readings.groupby(keys)[["machine_temp_c", "ambient_temp_c", "pressure_hpa",
                                  "humidity_pct"]].mean()
    table = wide.join(env).reset_index().rename(columns={
        "target": "position_mm", "feed_mm_min": "speed_mm_min", "machine_temp_c": "t_machine_c",
        "ambient_temp_c": "t_ambient_c"})
    return table
