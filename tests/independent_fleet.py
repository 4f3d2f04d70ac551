"""A fleet generator written independently of the twin (it never imports ``models.physics``):
its own machines, usage, measuring systems, wear forms and noise, so the fleet models are not
graded on the twin's own equations.

Five machines with two linear axes each, a maintenance visit every quarter:

- every axis has its own travel, targets (irregular ISO-style spacing), level and wear-rate
  map: the level rises linearly along the screw, the wear rate is a raised-cosine working
  zone on top of a small base rate (not the twin's Gaussian bump);
- usage differs by machine (hours per month), so the hour counters run at different speeds;
- two machines get a mechanical adjustment (new preload) with their hour counter running on:
  the lost motion drops to a new level and wear restarts there, nothing in the file says so;
- one machine joins the fleet late (two visits before the last);
- one machine measures through its rotary encoder (indirect: every reading carries the lost
  motion), the others through a linear scale (direct: only readings right after a reversal do);
- every visit runs a linear and a pendulum test (paired), five cycles each.

``fleet()`` returns the readings (docs/data-contract.md columns), the true lost motion per
machine, axis, visit and target (``truth``), and what each axis is (``axes``).
``fleet(rotary=True)`` gives the same machines two rotary axes instead (A and C: targets in
deg, lost motion and deviations in arcsec), with sizes of their own (``ROTARY``) and their own
random draws.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

START = pd.Timestamp("2025-01-06 07:30")
VISIT_DAYS = 91.0
CYCLES = 5
READING_SD_UM = 0.25       # laser reading noise
VISIT_SD_UM = 0.06         # day-to-day variation of the lost motion itself
N_TARGETS = 11


@dataclass(frozen=True)
class Kind:
    """The sizes of one kind of axis, in its units (um and mm, or arcsec and deg)."""

    names: tuple[str, ...]
    seed: int
    travels: tuple[float, ...]
    centred: bool             # targets symmetric about 0 (a tilting axis) or from 0
    level: tuple[float, float]
    level_slope: tuple[float, float]
    base_rate: tuple[float, float]     # per 1000 h
    zone_rate: tuple[float, float]     # per 1000 h
    reading_sd: float
    visit_sd: float
    setup_sd: float
    lead: float               # per 1000 position units
    thermal: float            # per 1000 position units and K
    periodic: float


LINEAR = Kind(("X", "Y"), 70_000, (400.0, 500.0, 630.0, 800.0), False, (1.2, 3.5),
              (-0.4, 0.6), (0.15, 0.4), (0.5, 1.4), READING_SD_UM, VISIT_SD_UM, 0.3,
              9.0, 11.0, 0.8)
# a worm-gear rotary table and a tilting axis: lost motion of tens of arcsec, a worm-wheel
# periodic error, an encoder read to about 2 arcsec
ROTARY = Kind(("A", "C"), 80_000, (120.0, 180.0, 240.0, 360.0), True, (12.0, 35.0),
              (-4.0, 6.0), (1.5, 4.0), (5.0, 14.0), 2.0, 0.6, 3.0, 20.0, 2.0, 6.0)


@dataclass(frozen=True)
class Machine:
    machine_id: str
    hours_per_month: float
    direct: bool
    first_visit: int = 1
    adjusted_at: int | None = None   # visit whose measurement follows the adjustment


MACHINES = (
    Machine("M1", 310.0, direct=True),
    Machine("M2", 420.0, direct=True, adjusted_at=5),
    Machine("M3", 180.0, direct=False),
    Machine("M4", 260.0, direct=True, adjusted_at=4),
    Machine("M5", 350.0, direct=True, first_visit=6),
)


# The fleet seen at its fifth visit, which follows two machines' adjustment: M2 and M4 adjusted
# a few weeks before visit 5, M5 joined at visit 3.
ADJUSTED_LAST = tuple(replace(m, adjusted_at=5 if m.adjusted_at else None,
                              first_visit=min(m.first_visit, 3)) for m in MACHINES)


def raised_cosine(x, centre, half_width):
    """1 at ``centre``, falling as cos^2 to 0 at ``half_width`` away, 0 beyond."""
    u = np.clip(np.abs(np.asarray(x, float) - centre) / half_width, 0.0, 1.0)
    return np.cos(0.5 * np.pi * u) ** 2


@dataclass(frozen=True)
class Axis:
    machine: Machine
    axis: str
    targets: np.ndarray
    level_um: float          # lost motion at the home end after assembly or adjustment
    level_slope_um: float    # rise of the level from home to far end
    base_rate: float         # um per 1000 h everywhere
    zone_rate: float         # um per 1000 h extra at the centre of the working zone
    zone_centre: float
    zone_half_width: float
    level_after_adjust_um: float
    kind: Kind = LINEAR

    def rate(self, x):
        """Wear rate [um per 1000 h] along the axis."""
        return self.base_rate + self.zone_rate * raised_cosine(x, self.zone_centre,
                                                               self.zone_half_width)

    def level(self, x, adjusted: bool):
        length = self.targets[-1] - self.targets[0]
        start = self.level_after_adjust_um if adjusted else self.level_um
        return start + self.level_slope_um * (np.asarray(x, float) - self.targets[0]) / length

    def lost_motion(self, x, hours_since: float, adjusted: bool, rate_after: float = 1.0):
        rate = self.rate(x) * (rate_after if adjusted else 1.0)
        return self.level(x, adjusted) + rate * hours_since / 1000.0


def make_axes(rng: np.random.Generator, kind: Kind = LINEAR,
              machines: tuple[Machine, ...] = MACHINES) -> list[Axis]:
    axes = []
    for machine in machines:
        for name in kind.names:
            travel = float(rng.choice(list(kind.travels)))
            t = np.linspace(0.0, travel, N_TARGETS)
            t[1:-1] += rng.uniform(-0.25, 0.25, N_TARGETS - 2) * travel / (N_TARGETS - 1)
            start = -travel / 2 if kind.centred else 0.0
            level = rng.uniform(*kind.level)
            axes.append(Axis(
                machine, name, np.round(t + start, 2), level, rng.uniform(*kind.level_slope),
                base_rate=rng.uniform(*kind.base_rate), zone_rate=rng.uniform(*kind.zone_rate),
                zone_centre=start + rng.uniform(0.3, 0.7) * travel,
                zone_half_width=rng.uniform(0.2, 0.35) * travel,
                level_after_adjust_um=level * rng.uniform(0.5, 0.8), kind=kind))
    return axes


def _cycle(method: str, n: int):
    """(target index, direction sign, cycle, follows a reversal) in reading order."""
    for c in range(1, CYCLES + 1):
        if method == "linear":
            yield from ((i, 1, c, i == 0) for i in range(n))
            yield from ((i, -1, c, i == n - 1) for i in reversed(range(n)))
        else:
            for i in range(n):
                yield (i, 1, c, True)
                yield (i, -1, c, True)


# With ``conditions``: the lost motion grows with feed (friction windup) and with the machine
# temperature (the nut's preload), linearly about 1000 mm/min and 20 °C; ``backlash_true_um``
# is then the lost motion there, and a test at feed f and temperature T shows
# backlash_true_um + SENSITIVITY_FEED (f - 1000) + SENSITIVITY_TEMP (T - 20).
CONDITIONS_FEEDS = (600.0, 900.0, 1400.0)  # mm/min: each visit runs two pairs at two of them
SENSITIVITY_FEED = 4e-4  # um per mm/min
SENSITIVITY_TEMP = 0.3   # um/K


def fleet(seed: int = 0, visits: int = 8, rotary: bool = False, rate_after: float = 1.0,
          machines: tuple[Machine, ...] = MACHINES, conditions: bool = False):
    """Readings, truth and axes of the fleet (module docstring); ``rotary``: its rotary axes;
    ``rate_after``: the wear rate after an adjustment relative to before (a new nut that
    wears at another pace; 1: the adjustment resets the clearance only); ``machines``: other
    machines than ``MACHINES`` (``ADJUSTED_LAST``: adjustments just before the last visit);
    ``conditions``: each visit runs a linear and a pendulum test at each of two feeds drawn
    from ``CONDITIONS_FEEDS``, each pair at its own temperature, and the lost motion depends
    on both (``SENSITIVITY_FEED``, ``SENSITIVITY_TEMP``)."""
    kind = ROTARY if rotary else LINEAR
    rng = np.random.default_rng(kind.seed + seed)
    axes = make_axes(rng, kind, machines)
    rows, truth = [], []
    for ax in axes:
        m = ax.machine
        hours_at_adjust = None
        for visit in range(m.first_visit, visits + 1):
            date = START + pd.Timedelta(days=VISIT_DAYS * (visit - 1) + rng.uniform(-5, 5))
            hours = m.hours_per_month * (visit - 1) * VISIT_DAYS / 30.4375 + rng.uniform(0, 20)
            adjusted = m.adjusted_at is not None and visit >= m.adjusted_at
            if adjusted and hours_at_adjust is None:  # adjusted a few weeks before the visit
                hours_at_adjust = hours - m.hours_per_month * rng.uniform(0.5, 1.5)
            since = hours - hours_at_adjust if adjusted else hours
            true = (ax.lost_motion(ax.targets, since, adjusted, rate_after)
                    + rng.normal(0, kind.visit_sd))
            truth += [{"machine_id": m.machine_id, "axis": ax.axis, "visit": str(visit),
                       "target": float(x), "backlash_true_um": float(b),
                       "operating_hours": hours, "hours_since_adjustment": since}
                      for x, b in zip(ax.targets, true)]
            if conditions:
                rows += _pairs_at_conditions(rng, ax, visit, true, date, hours)
                continue
            feed = 1000.0 + 500.0 * (int(m.machine_id[1]) % 3)
            temp = 21.0 + rng.normal(0, 0.6)
            for k, method in enumerate(("linear", "pendulum")):
                rows += _test(rng, ax, visit, method, true, date + pd.Timedelta(minutes=40 * k),
                              hours, feed, temp + 0.3 * k)
    readings = pd.DataFrame(rows)
    return readings, pd.DataFrame(truth), axes


def _pairs_at_conditions(rng, ax: Axis, visit: int, true: np.ndarray, date, hours) -> list:
    """Two linear + pendulum pairs of a visit at two feeds, each pair at its own machine
    temperature; the lost motion each pair shows is the truth at its mean conditions."""
    rows = []
    for p, feed in enumerate(rng.choice(CONDITIONS_FEEDS, size=2, replace=False)):
        temp = 21.0 + rng.normal(0, 0.6)
        shown = true + SENSITIVITY_FEED * (feed - 1000.0) + SENSITIVITY_TEMP * (temp + 0.15 - 20)
        for k, method in enumerate(("linear", "pendulum")):
            rows += _test(rng, ax, visit, method, shown,
                          date + pd.Timedelta(minutes=40 * (2 * p + k)), hours, float(feed),
                          temp + 0.3 * k, pair=p)
    return rows


def _test(rng, ax: Axis, visit: int, method: str, lost_motion: np.ndarray, start, hours,
          feed, temp, pair: int | None = None) -> list[dict]:
    m, k = ax.machine, ax.kind
    t = ax.targets
    length = t[-1] - t[0]
    # geometric error common to both directions: a lead error and thermal growth of the screw
    geometric = k.lead * (t - t[0]) / 1000.0 + k.thermal * (temp - 20.0) * (t - t[0]) / 1000.0 \
        + k.periodic * np.sin(2 * np.pi * (t - t[0]) / (0.37 * length))
    offset = rng.normal(0, k.setup_sd)  # setup offset of the laser per test
    test_id = f"{m.machine_id}{ax.axis}-v{visit}-{method[:3]}" + ("" if pair is None
                                                                   else f"-{pair}")
    out = []
    for i, sign, cycle, after_reversal in _cycle(method, len(t)):
        shows = (not m.direct) or after_reversal
        play = -sign * lost_motion[i] / 2.0 if shows else 0.0
        out.append({
            "machine_id": m.machine_id, "axis": ax.axis, "test_id": test_id, "method": method,
            "target": float(t[i]), "direction": "+" if sign > 0 else "-", "cycle": cycle,
            "deviation_um": geometric[i] + offset + play + rng.normal(0, k.reading_sd),
            "visit": str(visit), "repeat": 1, "started_at": start.isoformat(),
            "feed_mm_min": feed, "dwell_s": 2.0, "machine_temp_c": temp,
            "ambient_temp_c": 20.4 + rng.normal(0, 0.1), "pressure_hpa": 1012.0,
            "humidity_pct": 45.0, "operating_hours": round(hours, 1)})
    return out


def plan_and_truth(seed: int = 0, visits: int = 8, rotary: bool = False,
                   rate_after: float = 1.0):
    """Training readings (every visit but the last), the plan of the last visit (targets and
    conditions, no deviations) and its true lost motion (``rotary``: of the rotary axes)."""
    readings, truth, axes = fleet(seed, visits, rotary, rate_after)
    last = readings["visit"] == str(visits)
    keys = ["machine_id", "axis", "target", "operating_hours", "feed_mm_min", "dwell_s",
            "machine_temp_c"]
    plan = (readings[last & (readings["method"] == "pendulum")]
            .groupby(["machine_id", "axis", "target"], as_index=False)[keys[3:]].mean())
    plan["visit"] = str(visits)
    expected = truth[truth["visit"] == str(visits)]
    return readings[~last].reset_index(drop=True), plan, expected, axes
