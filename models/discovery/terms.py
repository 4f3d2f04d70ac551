"""The effects as design terms: typed nuisance parameters, the readings' conditions, the
unit-amplitude columns of an effect and the readings' repeatability."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pandas as pd

from features.readings import schema
from models.physics import effects

EFFECTS = effects.EFFECTS
MAX_CONTROL = 15    # control points of a general smooth form, at most (and one per target)
# readings columns -> the condition arrays derived from them
CONDITION_OF = {"measured_at": "elapsed_s"}
ALWAYS_PRESENT = ("target", "direction")
# nuisance values the measured targets fix (``data_value``)
DATA_WORDS = ("travel", "middle", "start", "stop")


# ------------------------------------------------------------------------------ nuisance
@dataclass(frozen=True)
class Nuisance:
    """One nuisance parameter of an effect record, as discovery treats it.

    ``kind`` is one of

    - ``"data"``: a value the measured targets fix (``word``: travel, middle, start, stop);
    - ``"targets"`` / ``"ends"``: searched over the measured targets / the two end targets;
    - ``"period"``: a period [mm] searched between ``values = (shortest, longest)``, on a grid
      uniform in frequency;
    - ``"values"``: searched over the grid ``values``;
    - ``"quadrature"``: a phase fitted in closed form (a sine and a cosine column) together
      with the amplitude parameter ``amplitude``;
    - ``"profile"``: the number of control points of a general smooth form.
    """

    key: str
    kind: str
    values: tuple[float, ...] = ()
    word: str = ""
    amplitude: str = ""

    @property
    def searched(self) -> bool:
        """Searched over a grid (profile likelihood)."""
        return self.kind in ("targets", "ends", "period", "values")

    @property
    def continuous(self) -> bool:
        """A continuous value that a bounded search may refine between grid values."""
        return self.kind in ("period", "values")

    def grid(self, x: np.ndarray) -> np.ndarray:
        """The values searched on targets ``x`` [mm] (empty when not searched)."""
        if self.kind == "targets":
            return np.unique(x)
        if self.kind == "ends":
            return np.array([float(np.min(x)), float(np.max(x))])
        if self.kind == "period":
            low, high = self.values
            step = 1.0 / (4.0 * max(float(np.ptp(x)), high))
            return 1.0 / np.arange(1.0 / high, 1.0 / low + step / 2, step)
        if self.kind == "values":
            return np.asarray(self.values, float)
        return np.empty(0)


def parse_nuisance(key: str, spec, amplitude: str) -> Nuisance:
    """The typed form of one entry of an effect record's ``nuisance`` table
    (``models.physics.effects``: a word, a tuple of values, ``("period", low, high)`` or
    ``("quadrature", amplitude)``); ``amplitude`` is the record's own amplitude parameter."""
    if spec in DATA_WORDS:
        return Nuisance(key, "data", word=spec)
    if spec in ("targets", "ends"):
        return Nuisance(key, spec)
    if spec == "per_target":
        return Nuisance(key, "profile")
    if spec == "quadrature":
        return Nuisance(key, "quadrature", amplitude=amplitude)
    if isinstance(spec, tuple) and spec and spec[0] == "quadrature":
        return Nuisance(key, "quadrature", amplitude=spec[1])
    if isinstance(spec, tuple) and spec and spec[0] == "period":
        return Nuisance(key, "period", values=(float(spec[1]), float(spec[2])))
    if isinstance(spec, tuple) and spec:
        return Nuisance(key, "values", values=tuple(float(v) for v in spec))
    raise ValueError(f"nuisance {key!r}: unknown grid {spec!r}")


@functools.cache
def nuisances(name: str) -> tuple[Nuisance, ...]:
    """The nuisance parameters of effect ``name``, typed, in the record's order."""
    record = EFFECTS[name]
    return tuple(parse_nuisance(k, v, record.amplitude) for k, v in record.nuisance.items())


def searched_nuisance(name: str) -> Nuisance | None:
    """The nuisance parameter searched over a grid (the first one), or None."""
    return next((n for n in nuisances(name) if n.searched), None)


def nuisance_grid(name: str, x: np.ndarray) -> tuple[str | None, np.ndarray | None]:
    """The searched nuisance parameter of an effect and its grid (None when nothing is
    searched)."""
    found = searched_nuisance(name)
    return (None, None) if found is None else (found.key, found.grid(x))


def quadrature_pairs(name: str) -> list[tuple[str, str]]:
    """(phase, amplitude) parameters fitted in closed form as sine and cosine columns."""
    return [(n.key, n.amplitude) for n in nuisances(name) if n.kind == "quadrature"]


# Effects whose natural form is a general profile along the axis (complexity by BIC).
PROFILES = tuple(name for name in EFFECTS if any(n.kind == "profile" for n in nuisances(name)))


def signed_by_approach(name: str) -> bool:
    """A profile along the axis that reads the approach direction: its general smooth form is
    the half-difference between the directions (``reversal_profile``), not a common one."""
    return name in PROFILES and "direction" in EFFECTS[name].inputs


# ------------------------------------------------------------------------------ data
def conditions_of(readings: pd.DataFrame) -> dict:
    """Per-reading arrays the effects read; absent inputs are left out."""
    cond = {c: readings[c].to_numpy(float) for c in schema.NUMERIC_OPTIONAL if c in readings}
    if "measured_at" in readings:
        measured = pd.to_datetime(readings["measured_at"])
        start = (pd.to_datetime(readings["started_at"]) if "started_at" in readings
                 else measured.groupby(readings["test_id"]).transform("min"))
        cond["elapsed_s"] = (measured - start).dt.total_seconds().to_numpy()
    return cond


def missing_inputs(name: str, cond: dict) -> list[str]:
    """Inputs of the effect's record that the readings lack (or hold gaps in)."""
    missing = []
    for column in EFFECTS[name].inputs:
        if column in ALWAYS_PRESENT:
            continue
        key = CONDITION_OF.get(column, column)
        if key not in cond or not np.isfinite(cond[key]).all():
            missing.append(column)
    return missing


def data_value(word: str, x: np.ndarray) -> float:
    """A nuisance value the measured targets fix (see ``models.physics.effects``)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    return {"travel": (hi - lo) or 1.0, "middle": (lo + hi) / 2, "start": lo,
            "stop": hi if hi > lo else lo + 1.0}[word]


def control_counts(x: np.ndarray) -> range:
    """Complexities of a general smooth form: 3 up to one control point per target."""
    return range(3, min(len(np.unique(x)), MAX_CONTROL) + 1)


def profile_basis(x: np.ndarray, n_control: int) -> np.ndarray:
    """Degree-2 B-spline basis over the measured travel ([Mechta2022], eq. 20) [-]."""
    t = effects.unit_interval(x, float(np.min(x)), data_value("stop", x))
    return effects.bspline_basis(t, n_control, 2)


def reversal_flags(readings: pd.DataFrame) -> np.ndarray:
    """Readings taken on a move that reversed the axis: every pendulum reading, and the
    turn-around targets of a linear cycle (first target approached +, last approached -)."""
    method = readings["method"].to_numpy()
    x = readings["target"].to_numpy(float)
    up = readings["direction"].to_numpy() == "+"
    test = readings["test_id"].to_numpy()
    lo = pd.Series(x).groupby(test).transform("min").to_numpy()
    hi = pd.Series(x).groupby(test).transform("max").to_numpy()
    return (method == "pendulum") | ((x == lo) & up) | ((x == hi) & ~up)


def effect_column(name: str, x, d, cond, nuisance: dict | None = None,
                  reversal: np.ndarray | None = None) -> np.ndarray:
    """The effect with unit amplitude as design column(s) [um per unit amplitude].

    ``nuisance`` may hold ``n_control`` (a general smooth form: one column per control point);
    ``reversal`` (direct measuring system) keeps lost motion on the readings that follow a
    reversal only."""
    record = EFFECTS[name]
    nuisance = dict(nuisance or {})
    if "n_control" in nuisance:
        value = profile_basis(x, int(nuisance["n_control"]))
        if signed_by_approach(name):  # the profile is the reversal value r(x): e = d r(x) / 2
            value = value * np.asarray(d, float)[:, None] / 2
    else:
        fixed = {n.key: data_value(n.word, x) for n in nuisances(name) if n.kind == "data"}
        pairs = quadrature_pairs(name)
        if pairs:  # amplitude and phase of each harmonic: a sine and a cosine column
            params = {**fixed, **nuisance, **{amp: 0.0 for _, amp in pairs}}
            value = np.column_stack([effects.contribution(name, x, d, cond,
                                                          **{**params, amp: 1.0, phase: ph})
                                     for phase, amp in pairs for ph in (0.0, np.pi / 2)])
        else:
            params = {**fixed, **nuisance, record.amplitude: 1.0}
            value = effects.contribution(name, x, d, cond, **params)
    value = value.reshape(len(x), -1)
    if record.kind != "lost_motion":
        return value
    seen = 1.0 if reversal is None else reversal[:, None]
    return -d[:, None] * value / 2 * seen


def repeatability_um(readings: pd.DataFrame) -> float:
    """Reading repeatability [um]: pooled von Neumann estimate over consecutive cycles of the
    same test, target and direction, s^2 = sum (x_(j+1) - x_j)^2 / (2 (n - 1)); a slow drift
    across the cycles (warm-up) does not inflate it the way the plain variance would."""
    ordered = readings.sort_values(["test_id", "target", "direction", "cycle"])
    keys = [ordered[k].to_numpy() for k in ("test_id", "target", "direction")]
    same = np.ones(len(ordered) - 1, bool)
    for k in keys:
        same &= k[1:] == k[:-1]
    step = np.diff(ordered["deviation_um"].to_numpy(float))[same]
    return float(np.sqrt(np.mean(step ** 2) / 2)) if step.size else float("nan")
