"""Find the physical effect a simulation is missing, name it, add it, show the gap shrink.

The simulation model is a set of named effects (``models.physics.effects``, one definition
each) fitted to the readings: every effect is linear in one amplitude once its nuisance
parameters (screw pitch, time constants, wear location) are fixed, and each run (test) gets its
own offset, the laser's datum. Lost-motion effects enter as -d b/2 (indirect measuring system:
every approach carries half the clearance against its direction d).

Loop (seed 000's rule: stop when the residual is within the repeatability):

1. fit the model, residual r = measured - model;
2. for every effect not in the model whose inputs the data have: refit model + candidate over
   the candidate's nuisance grid;
3. a candidate passes when all hold: delta BIC < -10; leave-one-run-out cross-validation
   improves the held-out RMSE by > 2 %; its fitted coefficient is physically plausible
   (``PLAUSIBLE``, e.g. steel's alpha, the Edlen fraction); and under a bootstrap by run it stays
   the best candidate in >= 80 % of resamples with a 95 % interval that excludes zero;
4. identifiability: passing candidates whose columns are collinear on this design (|r| > 0.95
   after the model is projected out) or whose gains are within 10 % of each other are reported
   ``ambiguous`` together, with the test that would separate them; otherwise the winner is named,
   added and the loop repeats.

Candidates collinear with the model's own terms on this design (thermal expansion, air
refraction and lead error are all proportional to position when conditions do not vary between
runs), and periodic errors aliased by the target spacing, are reported ``ambiguous`` with the
test that would separate them: the data cannot say whether they are present.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError
from models.physics import effects

DEFAULT_BASELINE = ("backlash", "lead_error_linear")
BIC_THRESHOLD = -10.0
CV_GAIN = 0.02
BOOT_SAMPLES = 40
BOOT_AGREEMENT = 0.8
COLLINEAR = 0.95
CLOSE_GAIN = 0.10
STOP_RATIO = 1.05  # residual within 5 % of the repeatability: nothing measurable left

# Per-effect knowledge (amplitude, plausible range, nuisance grids, inputs, separating test)
# lives in the effect records, ``models.physics.effects.RECORDS``.
RECORDS = effects.RECORDS
# readings columns -> the condition arrays derived from them
CONDITION_OF = {"measured_at": "elapsed_s"}
ALWAYS_PRESENT = ("target", "direction")
# general smooth forms (one control point per target at most): tried as fallbacks only
GENERAL_FORMS = tuple(name for name, r in RECORDS.items() if "per_target" in r.nuisance.values())


@dataclass
class Step:
    effect: str
    parameters: dict
    interval: dict
    delta_bic: float
    cv_gain: float
    rmse_before_um: float
    rmse_after_um: float


@dataclass
class Discovery:
    named: list = field(default_factory=list)
    ambiguous: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    rmse_before_um: float = float("nan")
    rmse_after_um: float = float("nan")
    repeatability_um: float = float("nan")
    notes: list = field(default_factory=list)
    evidence: list = field(default_factory=list)   # per step: candidate table
    residual_before: np.ndarray | None = None
    residual_after: np.ndarray | None = None

    def to_json(self) -> dict:
        return {"named": self.named, "ambiguous": self.ambiguous,
                "steps": [s.__dict__ for s in self.steps],
                "rmse_before_um": self.rmse_before_um, "rmse_after_um": self.rmse_after_um,
                "repeatability_um": self.repeatability_um, "notes": self.notes}


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
    for column in RECORDS[name].inputs:
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


def nuisance_grid(name: str, x: np.ndarray) -> tuple[str | None, np.ndarray | None]:
    """The searched nuisance parameter of an effect and its grid (None when nothing is
    searched)."""
    for key, grid in RECORDS[name].nuisance.items():
        if grid == "targets":
            return key, np.unique(x)
        if isinstance(grid, tuple):
            return key, np.asarray(grid, float)
    return None, None


def effect_column(name: str, x, d, cond, nuisance: dict | None = None) -> np.ndarray:
    """The effect with unit amplitude as a design column [um per unit amplitude]."""
    record = RECORDS[name]
    fixed = {k: data_value(v, x) for k, v in record.nuisance.items()
             if v in ("travel", "middle", "start", "stop")}
    params = {**fixed, **(nuisance or {}), record.amplitude: 1.0}
    quadrature = [k for k, v in record.nuisance.items() if v == "quadrature"]
    if quadrature:  # amplitude and phase: a sine and a cosine column
        value = np.column_stack([effects.contribution(name, x, d, cond, **params,
                                                      **{quadrature[0]: ph})
                                 for ph in (0.0, np.pi / 2)])
    else:
        value = effects.contribution(name, x, d, cond, **params)
    return -d[:, None] * value.reshape(len(x), -1) / 2 if record.kind == "lost_motion" else value


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


# ------------------------------------------------------------------------------ fitting
class Design:
    """Design columns with per-run offsets projected out (within-run demeaning)."""

    def __init__(self, readings: pd.DataFrame):
        self.y = readings["deviation_um"].to_numpy(float)
        self.x = readings["target"].to_numpy(float)
        self.d = np.where(readings["direction"].to_numpy() == "+", 1.0, -1.0)
        self.cond = conditions_of(readings)
        self.run = pd.factorize(readings["test_id"])[0]
        self.n_runs = self.run.max() + 1
        self.counts = np.bincount(self.run)

    def demean(self, a: np.ndarray) -> np.ndarray:
        a = a.reshape(len(self.y), -1)
        sums = np.zeros((self.n_runs, a.shape[1]))
        np.add.at(sums, self.run, a)
        return a - (sums / self.counts[:, None])[self.run]

    def column(self, name: str, nuisance: dict | None = None) -> np.ndarray:
        return self.demean(effect_column(name, self.x, self.d, self.cond, nuisance))


def lstsq_fit(X: np.ndarray, y: np.ndarray):
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    return coef, resid


def bic(sse: float, n: int, k: int) -> float:
    return n * math.log(max(sse, 1e-300) / n) + k * math.log(n)


def loro_rmse(X: np.ndarray, y: np.ndarray, run: np.ndarray, n_runs: int) -> float:
    """Leave-one-run-out RMSE: fit on the other runs, predict the left-out run (its offset is
    already removed by the demeaning)."""
    sse = 0.0
    for r in range(n_runs):
        out = run == r
        coef, *_ = np.linalg.lstsq(X[~out], y[~out], rcond=None)
        sse += float(np.sum((y[out] - X[out] @ coef) ** 2))
    return math.sqrt(sse / len(y))


# ------------------------------------------------------------------------------ the loop
def discover(readings: pd.DataFrame, baseline=DEFAULT_BASELINE, max_steps: int = 4,
             random_state: int = 0, source: str = "readings") -> Discovery:
    """Name the effects the baseline is missing (see the module docstring)."""
    baseline = check_baseline(baseline, source)
    design = Design(readings)
    result = Discovery(repeatability_um=repeatability_um(readings))
    skipped = {}
    for name in RECORDS:
        missing = missing_inputs(name, design.cond)
        if missing:
            skipped[name] = missing
            if name in baseline:
                raise InputError(f"baseline effect {name} needs column(s) "
                                 f"{', '.join(missing)}, which the readings lack", file=source)
    for name, missing in skipped.items():
        result.notes.append(f"candidate {name} skipped: the readings lack "
                            f"{', '.join(missing)}")
    model = {name: _best_nuisance(design, name, [])[0] for name in baseline}
    X = _stack(design, model)
    _, resid = lstsq_fit(X, design.demean(design.y)[:, 0])
    result.residual_before = resid
    result.rmse_before_um = _rmse(resid, design, X)
    rng = np.random.default_rng(random_state)
    for _ in range(max_steps):
        rmse_now = _rmse(resid, design, X)
        if rmse_now <= STOP_RATIO * result.repeatability_um:
            break
        table = _candidates(design, model, skipped)
        result.evidence.append(table)
        passing = table[table["passes"]]
        if passing.empty:
            break
        group = _ambiguous_group(design, model, passing)
        if len(group) > 1:
            result.ambiguous.append(sorted(group))
            break
        winner = passing.iloc[0]
        stable, interval = _bootstrap(design, model, winner, passing, rng)
        if not stable:
            result.notes.append(f"{winner['effect']} not stable under bootstrap by run; "
                                "not named")
            break
        model[winner["effect"]] = winner["nuisance"]
        X = _stack(design, model)
        _, resid = lstsq_fit(X, design.demean(design.y)[:, 0])
        result.named.append(winner["effect"])
        result.steps.append(Step(
            winner["effect"], {**winner["nuisance"], RECORDS[winner["effect"]].amplitude:
                               float(winner["coef"])},
            {RECORDS[winner["effect"]].amplitude: interval}, float(winner["delta_bic"]),
            float(winner["cv_gain"]), rmse_now, _rmse(resid, design, X)))
    result.residual_after = resid
    result.rmse_after_um = _rmse(resid, design, X)
    _confounding_notes(design, model, skipped, result)
    return result


def check_baseline(baseline, source: str = "readings") -> list[str]:
    names = [b.strip() for b in (baseline.split(",") if isinstance(baseline, str) else baseline)
             if b.strip()]
    for name in names:
        if name not in RECORDS:
            raise InputError(f"unknown effect {name!r} in --baseline; expected names from "
                             f"{', '.join(RECORDS)}", column="--baseline")
    return names


def _rmse(resid, design, X) -> float:
    dof = len(resid) - X.shape[1] - design.n_runs
    return math.sqrt(float(np.sum(resid ** 2)) / max(dof, 1))


def _stack(design: Design, model: dict) -> np.ndarray:
    return np.column_stack([design.column(name, nuisance) for name, nuisance in model.items()])


def _best_nuisance(design: Design, name: str, others: list) -> tuple[dict, float]:
    key, grid = nuisance_grid(name, design.x)
    if key is None:
        return {}, float("nan")
    y = design.demean(design.y)[:, 0]
    best = None
    for value in grid:
        cols = np.column_stack([*others, design.column(name, {key: float(value)})]) \
            if others else design.column(name, {key: float(value)})
        _, resid = lstsq_fit(cols, y)
        sse = float(np.sum(resid ** 2))
        if best is None or sse < best[1]:
            best = ({key: float(value)}, sse)
    return best


def _candidates(design: Design, model: dict, skipped: dict) -> pd.DataFrame:
    y = design.demean(design.y)[:, 0]
    base = _stack(design, model)
    _, resid0 = lstsq_fit(base, y)
    sse0 = float(np.sum(resid0 ** 2))
    n = len(y)
    cv0 = loro_rmse(base, y, design.run, design.n_runs)
    rows = []
    for name in RECORDS:
        if name in model or name in skipped or name in GENERAL_FORMS:
            continue
        nuisance, _ = _best_nuisance(design, name, [base])
        col = design.column(name, nuisance)
        if np.abs(col).max() < 1e-12:
            continue
        X = np.column_stack([base, col])
        coef, resid = lstsq_fit(X, y)
        sse = float(np.sum(resid ** 2))
        k_extra = col.shape[1] + (1 if nuisance else 0)
        delta_bic = bic(sse, n, base.shape[1] + k_extra) - bic(sse0, n, base.shape[1])
        cv_gain = 1 - loro_rmse(X, y, design.run, design.n_runs) / cv0
        amp = _amplitude(name, coef[base.shape[1]:])
        low, high = RECORDS[name].plausible
        plausible = low <= amp <= high
        rows.append({"effect": name, "nuisance": nuisance, "coef": amp, "delta_bic": delta_bic,
                     "cv_gain": cv_gain, "plausible": plausible, "sse": sse,
                     "passes": bool(delta_bic < BIC_THRESHOLD and cv_gain > CV_GAIN
                                    and plausible)})
    table = pd.DataFrame(rows)
    return table.sort_values("sse").reset_index(drop=True) if len(table) else \
        pd.DataFrame(columns=["effect", "passes"])


def _amplitude(name: str, coef: np.ndarray) -> float:
    if name == "lead_error_periodic":
        return float(np.hypot(*coef))
    return float(coef[0])


def _ambiguous_group(design: Design, model: dict, passing: pd.DataFrame) -> set:
    """The winner and every passing candidate it cannot be told apart from on this design."""
    winner = passing.iloc[0]
    base = _stack(design, model)
    proj = _projector(base)
    w = _residualise(design.column(winner["effect"], winner["nuisance"]), proj)
    baseline_sse = float(np.sum(_residualise(design.demean(design.y), proj) ** 2))
    winner_gain = baseline_sse - passing["sse"].iloc[0]
    group = {winner["effect"]}
    for _, other in passing.iloc[1:].iterrows():
        o = _residualise(design.column(other["effect"], other["nuisance"]), proj)
        close = baseline_sse - other["sse"] >= (1 - CLOSE_GAIN) * winner_gain
        if _max_corr(w, o) > COLLINEAR or close:
            group.add(other["effect"])
    return group


def _projector(base: np.ndarray):
    q, _ = np.linalg.qr(base)
    return q


def _residualise(col: np.ndarray, q: np.ndarray) -> np.ndarray:
    col = col.reshape(len(q), -1)
    return col - q @ (q.T @ col)


def _max_corr(a: np.ndarray, b: np.ndarray) -> float:
    best = 0.0
    for i in range(a.shape[1]):
        for j in range(b.shape[1]):
            na, nb = np.linalg.norm(a[:, i]), np.linalg.norm(b[:, j])
            if na > 1e-12 and nb > 1e-12:
                best = max(best, abs(float(a[:, i] @ b[:, j]) / (na * nb)))
    return best


def _bootstrap(design: Design, model: dict, winner, passing: pd.DataFrame, rng):
    """Resample runs with replacement: the winner must stay best among the passing candidates
    and its amplitude's 95 % interval must exclude zero."""
    y = design.demean(design.y)[:, 0]
    base = _stack(design, model)
    cols = {row["effect"]: design.column(row["effect"], row["nuisance"])
            for _, row in passing.iterrows()}
    wins, amps = 0, []
    for _ in range(BOOT_SAMPLES):
        runs = rng.integers(0, design.n_runs, design.n_runs)
        rows = np.concatenate([np.flatnonzero(design.run == r) for r in runs])
        sse = {}
        for name, col in cols.items():
            X = np.column_stack([base, col])[rows]
            coef, resid = lstsq_fit(X, y[rows])
            sse[name] = float(np.sum(resid ** 2))
            if name == winner["effect"]:
                amps.append(_amplitude(name, coef[base.shape[1]:]))
        wins += min(sse, key=sse.get) == winner["effect"]
    low, high = np.percentile(amps, [2.5, 97.5])
    stable = wins / BOOT_SAMPLES >= BOOT_AGREEMENT and (low > 0 or high < 0)
    return stable, [float(low), float(high)]


def _confounding_notes(design: Design, model: dict, skipped: dict, result: Discovery) -> None:
    """Candidates this design cannot see apart from the model, and aliased periodic errors."""
    base = _stack(design, model)
    proj = _projector(base)
    for name in RECORDS:
        if name in model or name in skipped or name in GENERAL_FORMS:
            continue
        col = design.column(name, _best_nuisance(design, name, [base])[0])
        total = float(np.sum(col ** 2))
        if total < 1e-12:
            continue
        left = float(np.sum(_residualise(col, proj) ** 2)) / total
        if left < 1e-3:
            twins = [m for m in model if _max_corr(col, design.column(m, model[m])) > COLLINEAR]
            test = RECORDS[name].separating_test
            result.notes.append(f"{name} cannot be told apart from {', '.join(twins) or 'the model'}"
                                f" on this design: {test}")
            if twins:
                _add_group(result.ambiguous, {name, *twins})
    spacing = np.diff(np.unique(design.x))
    if len(spacing) and "lead_error_periodic" not in model:
        pitches = nuisance_grid("lead_error_periodic", design.x)[1]
        aliased = [p for p in pitches if np.allclose(spacing / p, np.round(spacing / p), atol=1e-6)]
        if aliased:
            result.notes.append(
                "lead_error_periodic with a pitch of " + ", ".join(f"{p:g}" for p in aliased)
                + " mm is invisible at this target spacing: use ISO irregular target spacing")
            _add_group(result.ambiguous, {"lead_error_periodic"})


def _add_group(groups: list, members: set) -> None:
    """Add an ambiguous group, merging it with any group it shares an effect with."""
    for group in groups:
        if members & set(group):
            group[:] = sorted(members | set(group))
            return
    groups.append(sorted(members))
