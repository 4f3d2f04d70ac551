"""Find the physical effect a simulation is missing, name it, add it, show the gap shrink.

The simulation model is a set of named effects (``models.physics.effects.RECORDS``) fitted to
the readings: every effect is linear in its amplitude once its nuisance parameters (screw
pitch, time constants, wear location, number of control points) are fixed, and each run (test)
gets its own offset, the laser's datum. Lost-motion effects enter as -d b/2: on every reading
with an indirect measuring system, only on readings that follow a reversal with a direct one
(the system is chosen by the fit of the baseline and said in the notes).

Loop (seed 000's rule: stop when the residual is within the repeatability):

1. fit the model, residual r = measured - model;
2. for every effect not in the model whose inputs the data have: refit model + candidate over
   the candidate's nuisance grid (profile likelihood); general smooth forms (a degree-2
   B-spline along the axis with 3 up to one control point per target, for ``lead_error_profile``
   and for lost motion varying along the axis) choose their complexity by BIC;
3. a candidate passes when all hold: delta BIC < -10; cross-validation (leave one run out, or
   one cycle out for a single run) improves the held-out RMSE by > 2 %; its amplitude is
   physically plausible (the record's range, and lost motion never negative) for at least one
   member of the family of nuisance values the data cannot tell apart; and under a bootstrap
   (by run, or by cycle within runs when there are fewer than 8 runs) it stays the best candidate in >= 80 % of resamples with a 95 % interval that
   excludes zero;
4. identifiability: passing candidates whose BIC differ by less than 10 (columns collinear on
   this design fit equally well) are reported ``ambiguous`` together, with the tests that would separate them; a general smooth form wins
   over the specific effects only when its BIC is lower by more than 10 (it nests them);
   otherwise the winner is named, added and the loop repeats. A nuisance parameter the design
   cannot fix (two dwell levels for a settling time constant, aliased screw pitches) does not
   block the name: the step says which parameter is not identified and which test would fix it.

When nothing passes and the gap stays above the repeatability, ``unexplained`` says how large
the gap is and against what the residual is structured (position, direction, run, time,
temperature, feed, dwell), or that it is noise-dominated. Readings the ISO 230-2 step flags as
outliers are left out of the fit (said in the notes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features import iso230
from features.readings import schema
from features.readings.errors import InputError
from models.physics import effects

RECORDS = effects.RECORDS
DEFAULT_BASELINE = ("backlash", "lead_error_linear")
BIC_THRESHOLD = -10.0
CV_GAIN = 0.02
BOOT_SAMPLES = 40
BOOT_AGREEMENT = 0.8
BOOT_MIN_RUNS = 8   # fewer runs: resample cycles within runs instead of whole runs
COLLINEAR = 0.95
NESTED_SHARE = 0.9  # a specific effect with this share of a general form's gain stands in
CLOSE_BIC = 10.0    # candidates whose BIC differ by less than this cannot be told apart
STOP_RATIO = 1.05   # residual within 5 % of the repeatability: nothing measurable left
NOISE_RATIO = 2.0   # a single run whose gap is within twice the repeatability: noise-dominated
STRUCTURE_P = 0.01  # significance of a residual structure (F-test), Bonferroni over factors
MAX_CONTROL = 15    # control points of a general smooth form, at most (and one per target)
# readings columns -> the condition arrays derived from them
CONDITION_OF = {"measured_at": "elapsed_s"}
ALWAYS_PRESENT = ("target", "direction")
# Effects whose natural form is a general profile along the axis (complexity by BIC).
PROFILES = tuple(name for name, r in RECORDS.items() if "per_target" in r.nuisance.values())
# Lost motion along the axis: its record is a wear bump; the general smooth form is tried too.
LOST_MOTION_PROFILE = "backlash_position"
COMPENSATE_HINT = ("a compensation table can correct it: backlash compensate (pitch-error "
                   "and reversal tables per target)")
# residual structure: factor -> readings column(s) an effect acting along it would need
FACTOR_INPUTS = {"position": "target", "direction": "direction",
                 "position x direction": "target", "run x position": "target",
                 "cycle": "measured_at", "time": "measured_at",
                 "temperature": "machine_temp_c", "feed": "feed_mm_min", "dwell": "dwell_s"}


@dataclass
class Step:
    effect: str
    parameters: dict
    interval: dict
    delta_bic: float
    cv_gain: float
    rmse_before_um: float
    rmse_after_um: float
    not_identified: dict = field(default_factory=dict)


@dataclass
class Discovery:
    named: list = field(default_factory=list)
    ambiguous: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    rmse_before_um: float = float("nan")
    rmse_after_um: float = float("nan")
    repeatability_um: float = float("nan")
    notes: list = field(default_factory=list)
    unexplained: dict | None = None
    evidence: list = field(default_factory=list)   # per step: candidate table
    residual_before: np.ndarray | None = None
    residual_after: np.ndarray | None = None
    used: np.ndarray | None = None                 # readings kept in the fit (mask)

    def to_json(self) -> dict:
        return {"named": self.named, "ambiguous": self.ambiguous,
                "steps": [s.__dict__ for s in self.steps],
                "rmse_before_um": self.rmse_before_um, "rmse_after_um": self.rmse_after_um,
                "repeatability_um": self.repeatability_um, "notes": self.notes,
                "unexplained": self.unexplained}


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
        if grid == "ends":
            return key, np.array([float(np.min(x)), float(np.max(x))])
        if isinstance(grid, tuple) and grid and grid[0] == "quadrature":
            continue
        if isinstance(grid, tuple) and grid and grid[0] == "period":
            _, low, high = grid
            step = 1.0 / (4.0 * max(float(np.ptp(x)), high))
            return key, 1.0 / np.arange(1.0 / high, 1.0 / low + step / 2, step)
        if isinstance(grid, tuple):
            return key, np.asarray(grid, float)
    return None, None


def control_counts(x: np.ndarray) -> range:
    """Complexities of a general smooth form: 3 up to one control point per target."""
    return range(3, min(len(np.unique(x)), MAX_CONTROL) + 1)


def profile_basis(x: np.ndarray, n_control: int) -> np.ndarray:
    """Degree-2 B-spline basis over the measured travel (seed 000, eq. 20) [-]."""
    t = effects.unit_interval(x, float(np.min(x)), data_value("stop", x))
    return effects.bspline_basis(t, n_control, 2)


def quadrature_pairs(name: str) -> list[tuple[str, str]]:
    """(phase, amplitude) parameters fitted in closed form as sine and cosine columns."""
    record = RECORDS[name]
    pairs = []
    for key, grid in record.nuisance.items():
        if grid == "quadrature":
            pairs.append((key, record.amplitude))
        elif isinstance(grid, tuple) and grid and grid[0] == "quadrature":
            pairs.append((key, grid[1]))
    return pairs


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
    record = RECORDS[name]
    nuisance = dict(nuisance or {})
    if "n_control" in nuisance:
        value = profile_basis(x, int(nuisance["n_control"]))
    else:
        fixed = {k: data_value(v, x) for k, v in record.nuisance.items()
                 if v in ("travel", "middle", "start", "stop")}
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
        self._onehot = np.eye(self.n_runs)[self.run]
        self._means = self._onehot / self.counts
        self.cycle = readings["cycle"].to_numpy(int)
        self.reversal_flags = reversal_flags(readings)
        self.system = "indirect"
        # cross-validation and bootstrap units: runs, or cycles of a single run
        self.fold = self.run if self.n_runs >= 2 else pd.factorize(self.cycle)[0]
        self.n_folds = self.fold.max() + 1
        self.y0 = self.demean(self.y)[:, 0]
        self._cache = {}

    @property
    def reversal(self):
        return self.reversal_flags if self.system == "direct" else None

    def demean(self, a: np.ndarray) -> np.ndarray:
        a = a.reshape(len(self.y), -1)
        return a - self._means @ (self._onehot.T @ a)

    def column(self, name: str, nuisance: dict | None = None) -> np.ndarray:
        key = (name, self.system, tuple(sorted((nuisance or {}).items())))
        if key not in self._cache:
            self._cache[key] = self.demean(effect_column(name, self.x, self.d, self.cond,
                                                         nuisance, self.reversal))
        return self._cache[key]


def lstsq_fit(X: np.ndarray, y: np.ndarray):
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    return coef, resid


def bic(sse: float, n: int, k: int) -> float:
    return n * math.log(max(sse, 1e-300) / n) + k * math.log(n)


def rank(X: np.ndarray) -> int:
    return int(np.linalg.matrix_rank(X)) if X.size else 0


def cv_rmse(X: np.ndarray, y: np.ndarray, fold: np.ndarray, n_folds: int) -> float:
    """Held-out RMSE: fit on the other runs (cycles), predict the left-out one (its offset is
    already removed by the demeaning)."""
    sse = 0.0
    for r in range(n_folds):
        out = fold == r
        coef, *_ = np.linalg.lstsq(X[~out], y[~out], rcond=None)
        sse += float(np.sum((y[out] - X[out] @ coef) ** 2))
    return math.sqrt(sse / len(y))


# ------------------------------------------------------------------------------ the loop
def discover(readings: pd.DataFrame, baseline=DEFAULT_BASELINE, max_steps: int = 4,
             random_state: int = 0, source: str = "readings") -> Discovery:
    """Name the effects the baseline is missing (see the module docstring)."""
    baseline = check_baseline(baseline, source)
    result = Discovery(repeatability_um=repeatability_um(readings))
    flagged = iso230.outliers(readings).to_numpy()
    if flagged.any():
        result.notes.append(
            f"{int(flagged.sum())} reading(s) flagged as outliers by the ISO 230-2 step left "
            "out of the fit (they still count in the repeatability)")
    result.used = ~flagged
    design = Design(readings.loc[~flagged].reset_index(drop=True))
    skipped = _skipped(design, baseline, source, result)
    model = {name: {} for name in baseline}
    _choose_system(design, model, result)
    X = _stack(design, model)
    _, resid = lstsq_fit(X, design.y0)
    result.residual_before = resid
    result.rmse_before_um = _rmse(resid, design, X)
    rng = np.random.default_rng(random_state)
    barred = set()  # general forms a named specific effect stood in for
    single_noise = (design.n_runs == 1
                    and result.rmse_before_um <= NOISE_RATIO * result.repeatability_um)
    if design.n_runs == 1:
        result.notes.append("one run only: cross-validation leaves out one cycle at a time; "
                            "repeat the test (other feed, dwell or temperature) to separate "
                            "effects that act between runs")
    for _ in range(0 if single_noise else max_steps):
        rmse_now = _rmse(resid, design, X)
        if rmse_now <= STOP_RATIO * result.repeatability_um:
            break
        table = _candidates(design, model, skipped, result.repeatability_um, barred)
        result.evidence.append(table.drop(columns=["family"], errors="ignore"))
        passing = table[table["passes"]]
        if passing.empty:
            break
        sse0 = float(np.sum(lstsq_fit(X, design.y0)[1] ** 2))
        winner, group, stand_in = _choose(design, model, passing, sse0)
        if len(group) > 1:
            result.ambiguous.append(sorted(group))
            tests = sorted({RECORDS[g].separating_test for g in group})
            result.notes.append(f"{', '.join(sorted(group))} explain the gap equally well on "
                                f"this design: {'; '.join(tests)}")
            break
        stable, interval = _bootstrap(design, model, winner, passing, rng)
        if not stable:
            result.notes.append(f"{winner['effect']} not stable under bootstrap by "
                                f"{'run' if design.n_runs >= BOOT_MIN_RUNS else 'cycle'}; "
                                "not named")
            break
        name = winner["effect"]
        if stand_in:  # what is left is the shape difference, not another effect
            barred.update({stand_in, *(e for e in RECORDS if _nested(e, stand_in))})
            result.notes.append(
                f"{name} named rather than the general {stand_in} form, which fits slightly "
                f"better (the effect's shape differs a little from the record's): "
                f"{RECORDS[name].separating_test}")
        model[name] = winner["nuisance"]
        X = _stack(design, model)
        coef, resid = lstsq_fit(X, design.y0)
        result.named.append(name)
        step = Step(name, _parameters(design, model, name, coef, winner),
                    {winner["amplitude"]: interval}, float(winner["delta_bic"]),
                    float(winner["cv_gain"]), rmse_now, _rmse(resid, design, X),
                    winner["not_identified"])
        result.steps.append(step)
        for key, info in step.not_identified.items():
            result.notes.append(f"{name} named, but its {key} is not identified by this design "
                                f"(any of {info['range'][0]:g}-{info['range'][1]:g} fits as "
                                f"well): {info['test']}")
        if name in PROFILES or "n_control" in winner["nuisance"] or name == LOST_MOTION_PROFILE:
            result.notes.append(f"{name} varies along the axis: {COMPENSATE_HINT}")
    result.residual_after = resid
    result.rmse_after_um = _rmse(resid, design, X)
    _confounding_notes(design, model, skipped, result)
    result.unexplained = _unexplained(design, resid, result, single_noise)
    return result


def check_baseline(baseline, source: str = "readings") -> list[str]:
    """The baseline's effect names: known, distinct, at least one."""
    names = [b.strip() for b in (baseline.split(",") if isinstance(baseline, str) else baseline)]
    if not any(names):
        raise InputError("empty --baseline; expected comma-separated effect names from "
                         f"{', '.join(RECORDS)}", column="--baseline")
    for name in names:
        if name not in RECORDS:
            raise InputError(f"unknown effect {name!r} in --baseline; expected names from "
                             f"{', '.join(RECORDS)}", column="--baseline")
    if len(set(names)) < len(names):
        raise InputError("an effect is listed twice in --baseline", column="--baseline")
    return names


def _skipped(design: Design, baseline: list, source: str, result: Discovery) -> dict:
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
    return skipped


def _choose_system(design: Design, model: dict, result: Discovery) -> None:
    """Indirect or direct measuring system: whichever fits the baseline's lost motion better
    (they differ only where some readings do not follow a reversal)."""
    if not any(RECORDS[m].kind == "lost_motion" for m in model) or design.reversal_flags.all():
        return
    sse = {}
    for system in ("indirect", "direct"):
        design.system = system
        sse[system] = float(np.sum(lstsq_fit(_stack(design, model), design.y0)[1] ** 2))
    design.system = min(sse, key=sse.get)
    if design.system == "direct":
        result.notes.append("lost motion shows only on readings that follow a reversal: direct "
                            "measuring system (linear scale) assumed")


def _rmse(resid, design, X) -> float:
    dof = len(resid) - X.shape[1] - design.n_runs
    return math.sqrt(float(np.sum(resid ** 2)) / max(dof, 1))


def _stack(design: Design, model: dict) -> np.ndarray:
    return np.column_stack([design.column(name, nuisance) for name, nuisance in model.items()])


# ------------------------------------------------------------------------------ candidates
def _forms(design: Design, name: str) -> list[tuple[str, list[dict]]]:
    """The forms a candidate is tried in, each with its nuisance family: ('specific', grid of
    nuisance dicts) or ('general', complexities)."""
    forms = []
    if name not in PROFILES:
        key, grid = nuisance_grid(name, design.x)
        forms.append(("specific", [{}] if key is None else [{key: float(v)} for v in grid]))
    if name in PROFILES or name == LOST_MOTION_PROFILE:
        forms.append(("general", [{"n_control": k} for k in control_counts(design.x)]))
    return forms


def _candidates(design: Design, model: dict, skipped: dict, noise: float,
                barred: set = frozenset()) -> pd.DataFrame:
    y = design.y0
    base = _stack(design, model)
    _, resid0 = lstsq_fit(base, y)
    sse0 = float(np.sum(resid0 ** 2))
    n, k0 = len(y), rank(base)
    cv0 = cv_rmse(base, y, design.fold, design.n_folds)
    rows = []
    for name in RECORDS:
        if name in model or name in skipped:
            continue
        for form, family in _forms(design, name):
            if form == "general" and name in barred:
                continue
            row = _evaluate(design, model, base, name, form, family, sse0, n, k0, noise)
            if row is None:
                continue
            X = np.column_stack([base, design.column(name, row["nuisance"])])
            row["cv_gain"] = 1 - cv_rmse(X, y, design.fold, design.n_folds) / cv0
            row["passes"] = bool(row["delta_bic"] < BIC_THRESHOLD and row["cv_gain"] > CV_GAIN
                                 and row["plausible"])
            rows.append(row)
    table = pd.DataFrame(rows)
    return table.sort_values("delta_bic").reset_index(drop=True) if len(table) else \
        pd.DataFrame(columns=["effect", "form", "passes"])


def _evaluate(design, model, base, name, form, family, sse0, n, k0, noise):
    """Fit the candidate over its nuisance family; keep the best by BIC, and the family of
    values the data cannot tell from it (profile likelihood within chi2(1, 95 %))."""
    proj = _projector(base)
    r0 = _residualise(design.y0, proj)[:, 0]
    search = _search_penalty(family, n) if form == "specific" else 0.0
    fits = []
    for members in _batches(design, name, family):
        cols = np.stack([design.column(name, nz) for nz in members])
        for nuisance, col, (sse, coef, k) in zip(members, cols, _fit_batch(cols, proj, r0)):
            if k:
                fits.append((bic(sse, n, k0 + k + search), sse, nuisance, coef, col,
                             k0 + k + search))
    if not fits:
        return None
    best = min(fits, key=lambda f: f[0])
    if (form == "specific" and best[2] and isinstance(_grid_kind(name), tuple)
            and family[0] != best[2] and family[-1] != best[2]):
        fits.append(_refine(design, name, family, best, k0 + search, proj, r0, n))
        best = min(fits, key=lambda f: f[0])
    sigma2 = best[1] / max(n - best[5] - design.n_runs, 1)
    family_fits = [f for f in fits if f[1] - best[1] <= 3.84 * sigma2] \
        if form == "specific" else [best]
    not_identified = _not_identified(name, family, [f[2] for f in family_fits])
    not_identified.update(_undersampled(design, name, best[2], family_fits))
    # plausibility over the whole family only when the design cannot fix the nuisance
    judged = [(f, _amplitude(design, model, _base_coef(base, design.y0, f), name, f[2], f[3],
                             noise))
              for f in (family_fits if not_identified else [best])]
    plausible = [(f, a) for f, a in judged if a[1]]
    chosen, (amp, ok) = min(plausible, key=lambda p: p[0][1]) if plausible else judged[0]
    return {"effect": name, "form": form, "nuisance": chosen[2], "coef": amp,
            "amplitude": "peak_um" if "n_control" in chosen[2] else RECORDS[name].amplitude,
            "delta_bic": chosen[0] - bic(sse0, n, k0), "plausible": ok, "sse": chosen[1],
            "not_identified": not_identified, "family": len(family_fits)}


def _batches(design, name, family):
    """Members of a family grouped by their number of columns (stacked and fitted at once)."""
    groups = {}
    for nuisance in family:
        groups.setdefault(design.column(name, nuisance).shape[1], []).append(nuisance)
    return list(groups.values())


def _fit_batch(cols: np.ndarray, q: np.ndarray, r0: np.ndarray):
    """Least squares of the baseline's residual on each candidate's columns with the model
    projected out (Frisch-Waugh-Lovell), for a stack of candidates (M, n, m) at once: the
    residual sum of squares, the candidate's coefficients and the rank it adds."""
    cr = cols - np.einsum("nk,Mkm->Mnm", q, np.einsum("nk,Mnm->Mkm", q, cols))
    scale = np.linalg.norm(cols, axis=1)                       # (M, m)
    scale = np.where(scale > 1e-12, scale, 1.0)
    crs = cr / scale[:, None, :]
    gram = np.einsum("Mnm,Mnp->Mmp", crs, crs)
    rhs = np.einsum("Mnm,n->Mm", crs, r0)
    ranks = np.sum(np.linalg.svd(gram, compute_uv=False) > 1e-10, axis=1)
    coef_s = np.einsum("Mmp,Mp->Mm", np.linalg.pinv(gram, rcond=1e-10, hermitian=True), rhs)
    sse = float(r0 @ r0) - np.einsum("Mm,Mm->M", coef_s, rhs)
    return [(max(float(e), 0.0), c / sc, int(k)) for e, c, sc, k in
            zip(sse, coef_s, scale, ranks)]


def _base_coef(base: np.ndarray, y: np.ndarray, fit) -> np.ndarray:
    """The model's own coefficients with the candidate ``fit`` in it."""
    return lstsq_fit(base, y - fit[4] @ fit[3])[0]


def _undersampled(design: Design, name: str, nuisance: dict, family_fits: list) -> dict:
    """A period shorter than twice the closest target spacing: the targets cannot resolve it
    (its aliases fit as well wherever the spacing is regular)."""
    key = next(iter(nuisance), None)
    grid = RECORDS[name].nuisance.get(key) if key else None
    if not (isinstance(grid, tuple) and grid and grid[0] == "period"):
        return {}
    spacing = float(np.min(np.diff(np.unique(design.x)))) if len(np.unique(design.x)) > 1 else 0
    if spacing <= nuisance[key] / 2:
        return {}
    values = sorted({round(f[2][key], 3) for f in family_fits})
    return {key: {"range": [values[0], values[-1]], "values": values[:12],
                  "test": RECORDS[name].separating_test}}


def _search_penalty(family: list, n: int) -> float:
    """Parameters charged for a nuisance searched over a grid: one for the value, plus the
    look-elsewhere cost of picking the best of M values (2 ln M, as a Bonferroni bound), in
    units of BIC's ln(n) per parameter."""
    if len(family) < 2:
        return 0.0
    return 1.0 + 2.0 * math.log(len(family)) / math.log(n)


def _grid_kind(name: str):
    key, _ = nuisance_grid(name, np.zeros(1))
    return RECORDS[name].nuisance.get(key) if key else None


def _refine(design, name, family, best, k_base, proj, r0, n):
    """Refine a continuous nuisance between the best grid value's neighbours (a pitch or time
    constant off the grid), by bounded scalar minimisation of the residual sum of squares."""
    from scipy.optimize import minimize_scalar

    key = next(iter(best[2]))
    grid = [f[key] for f in family]
    i = grid.index(best[2][key])
    lo, hi = sorted((grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]))

    def fit(value):
        col = design.column(name, {key: float(value)})
        return col, _fit_batch(col[None], proj, r0)[0]

    found = minimize_scalar(lambda v: fit(v)[1][0], bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-3 * (hi - lo)})
    col, (sse, coef, k) = fit(found.x)
    return (bic(sse, n, k_base + k), sse, {key: float(found.x)}, coef, col, k_base + k)


def _amplitude(design, model, base_coef, name, nuisance, coef, noise) -> tuple[float, bool]:
    """The fitted amplitude and whether it is physically plausible. Profiles report their
    largest departure from a straight line over the targets (a straight line is the lead error
    and the offsets); lost motion must stay >= 0 along the axis."""
    record = RECORDS[name]
    if "n_control" in nuisance:
        targets = np.unique(design.x)
        profile = profile_basis(targets, nuisance["n_control"]) @ coef
        line = np.polyval(np.polyfit(targets, profile, 1), targets)
        amp = float(np.max(np.abs(profile - line)))
        ok = amp <= record.plausible[1] if record.kind == "position" else amp <= 50.0
    elif quadrature_pairs(name):
        amp = float(np.hypot(*coef[:2]))
        ok = record.plausible[0] <= amp <= record.plausible[1]
    else:
        amp = float(coef[0])
        ok = record.plausible[0] <= amp <= record.plausible[1]
    if ok and record.kind == "lost_motion" and "backlash" in model:
        b0 = float(base_coef[_column_start(design, model, "backlash")])
        shape = _lost_motion_shape(design, name, nuisance, coef)
        ok = b0 + float(np.percentile(shape, 5)) >= -noise
    return amp, ok


def _column_start(design: Design, model: dict, name: str) -> int:
    """Index of the effect's first column in the model's design matrix."""
    before = list(model)[:list(model).index(name)]
    return int(sum(design.column(m, model[m]).shape[1] for m in before))


def _lost_motion_shape(design, name, nuisance, coef) -> np.ndarray:
    """The candidate's lost motion at the measured targets and conditions [um]."""
    if "n_control" in nuisance:
        return profile_basis(np.unique(design.x), nuisance["n_control"]) @ coef
    record = RECORDS[name]
    params = {**nuisance, record.amplitude: float(coef[0])}
    return effects.contribution(name, design.x, 0, design.cond, **params)


def _not_identified(name: str, family: list[dict], equivalent: list[dict]) -> dict:
    """A nuisance parameter the design cannot fix: its equally good values span the whole grid
    or fall apart into separate groups (aliases)."""
    if len(equivalent) < 2 or len(family) < 3:
        return {}
    key = next(iter(family[0]))
    grid = [f[key] for f in family]
    idx = sorted({int(np.argmin(np.abs(np.asarray(grid) - e[key]))) for e in equivalent})
    spans = idx[0] == 0 and idx[-1] == len(grid) - 1
    split = bool(np.any(np.diff(idx) > 1))
    if not (spans or split):
        return {}
    values = [grid[i] for i in idx]
    return {key: {"range": [float(min(values)), float(max(values))],
                  "values": [float(v) for v in values][:12],
                  "test": RECORDS[name].separating_test}}


def _choose(design: Design, model: dict, passing: pd.DataFrame, sse0: float):
    """The winner among the passing candidates and its ambiguity group. A general smooth form
    nests the specific effects along the same input, so it wins only by a decisive BIC margin,
    is never grouped with them, and yields to a nested specific effect that gives at least
    ``NESTED_SHARE`` of its gain with an identified shape, or predicts held-out targets at
    least as well (leave one target out): then the general form only describes the specific
    effect's shape a little better, not another effect. The third value names
    the general form the specific one stood in for (or None)."""
    specific = passing[passing["form"] == "specific"]
    general = passing[passing["form"] == "general"]
    if len(general) and (specific.empty or general["delta_bic"].iloc[0]
                         < specific["delta_bic"].iloc[0] + BIC_THRESHOLD):
        winner = general.iloc[0]
        nested = specific[[_nested(e, winner["effect"]) for e in specific["effect"]]]
        if len(nested):
            rival = nested.iloc[0]
            # most of the gain with a fixed shape, unless an unresolved pitch lets it alias
            share = (sse0 - rival["sse"]) / max(sse0 - winner["sse"], 1e-300)
            if ((share >= NESTED_SHARE and not rival["not_identified"])
                    or _target_cv(design, model, rival) <= _target_cv(design, model, winner)):
                return rival, _ambiguous_group(design, model, rival, nested), \
                    winner["effect"]
        return winner, _ambiguous_group(design, model, winner,
                                        general.drop_duplicates("effect")), None
    winner = specific.iloc[0]
    return winner, _ambiguous_group(design, model, winner,
                                    specific.drop_duplicates("effect")), None


def _target_cv(design: Design, model: dict, candidate) -> float:
    """Held-out RMSE of model + candidate, leaving out one target position at a time: how
    well the candidate's shape predicts the error where it was not fitted."""
    X = np.column_stack([_stack(design, model),
                         design.column(candidate["effect"], candidate["nuisance"])])
    fold = pd.factorize(design.x)[0]
    return cv_rmse(X, design.y0, fold, int(fold.max()) + 1)


def _nested(specific: str, general: str) -> bool:
    """A specific effect the general smooth form can represent: same kind, same inputs."""
    a, b = RECORDS[specific], RECORDS[general]
    return a.kind == b.kind and set(a.inputs) == set(b.inputs)


def _ambiguous_group(design: Design, model: dict, winner, pool: pd.DataFrame) -> set:
    """The winner and every candidate of its pool it cannot be told apart from here: BIC
    within ``CLOSE_BIC`` (columns collinear on this design fit equally well and land here)."""
    group = {winner["effect"]}
    for _, other in pool.iterrows():
        if other["delta_bic"] - winner["delta_bic"] < CLOSE_BIC:
            group.add(other["effect"])
    return group


def _projector(base: np.ndarray):
    """Orthonormal basis of the model's column space."""
    u, sv, _ = np.linalg.svd(base, full_matrices=False)
    return u[:, sv > 1e-10 * max(float(sv.max(initial=0.0)), 1e-300)]


def _residualise(col: np.ndarray, q: np.ndarray) -> np.ndarray:
    col = col.reshape(len(q), -1)
    return col - q @ (q.T @ col)


def _max_corr(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = np.linalg.norm(a, axis=0), np.linalg.norm(b, axis=0)
    keep_a, keep_b = na > 1e-12, nb > 1e-12
    if not keep_a.any() or not keep_b.any():
        return 0.0
    corr = (a[:, keep_a] / na[keep_a]).T @ (b[:, keep_b] / nb[keep_b])
    return float(np.abs(corr).max())


def _bootstrap(design: Design, model: dict, winner, passing: pd.DataFrame, rng):
    """Resample runs (cycles of a single run) with replacement: the winner must stay the best
    (by BIC) among the passing candidates of its kind, and its amplitude's 95 % interval must
    exclude zero."""
    y = design.y0
    base = _stack(design, model)
    rivals = passing[passing["form"] == winner["form"]].drop_duplicates("effect")
    cols = {row["effect"]: design.column(row["effect"], row["nuisance"])
            for _, row in rivals.iterrows()}
    wins, amps = 0, []
    for _ in range(BOOT_SAMPLES):
        rows = _resample(design, rng)
        score = {}
        for name, col in cols.items():
            X = np.column_stack([base, col])[rows]
            coef, resid = lstsq_fit(X, y[rows])
            score[name] = bic(float(np.sum(resid ** 2)), len(rows), col.shape[1])
            if name == winner["effect"]:
                amp, _ = _amplitude(design, model, coef[:base.shape[1]], name,
                                    winner["nuisance"], coef[base.shape[1]:], 0.0)
                amps.append(amp)
        wins += min(score, key=score.get) == winner["effect"]
    low, high = np.percentile(amps, [2.5, 97.5])
    stable = wins / BOOT_SAMPLES >= BOOT_AGREEMENT and (low > 0 or high < 0)
    return stable, [float(low), float(high)]


def _resample(design: Design, rng) -> np.ndarray:
    """Rows of one bootstrap sample: whole runs drawn with replacement when there are enough
    runs to resample, else cycles drawn with replacement within each run (keeps the design's
    levels of feed, dwell and temperature)."""
    if design.n_runs >= BOOT_MIN_RUNS:
        units = [np.flatnonzero(design.run == r) for r in range(design.n_runs)]
        return np.concatenate([units[r] for r in rng.integers(0, design.n_runs, design.n_runs)])
    rows = []
    for r in range(design.n_runs):
        in_run = design.run == r
        cycles = np.unique(design.cycle[in_run])
        for c in rng.choice(cycles, len(cycles)):
            rows.append(np.flatnonzero(in_run & (design.cycle == c)))
    return np.concatenate(rows)


def _parameters(design: Design, model: dict, name: str, coef: np.ndarray, winner) -> dict:
    """The named effect's fitted parameters: its nuisance values, its amplitude, and for a
    general smooth form the control points [um] at their positions [mm]."""
    own = coef[_column_start(design, model, name):]
    nuisance = dict(winner["nuisance"])
    params = {**nuisance, winner["amplitude"]: float(winner["coef"])}
    if "n_control" in nuisance:
        lo, hi = float(design.x.min()), data_value("stop", design.x)
        params["form"] = "B-spline degree 2"
        params["control_um"] = [round(float(c), 4) for c in own]
        params["control_mm"] = [round(float(p), 3) for p in
                                np.linspace(lo, hi, int(nuisance["n_control"]))]
    elif quadrature_pairs(name):
        for i, (phase, amp) in enumerate(quadrature_pairs(name)):
            sin_c, cos_c = own[2 * i], own[2 * i + 1]
            params[phase] = float(np.arctan2(cos_c, sin_c))
            params[amp] = float(np.hypot(sin_c, cos_c))
    return params


# ------------------------------------------------------------------------------ reporting
def _confounding_notes(design: Design, model: dict, skipped: dict, result: Discovery) -> None:
    """Candidates this design cannot see apart from the model, and aliased periodic errors."""
    base = _stack(design, model)
    proj = _projector(base)
    for name in RECORDS:
        if name in model or name in skipped or name in PROFILES:
            continue
        key, grid = nuisance_grid(name, design.x)
        nuisance = {} if key is None else {key: float(grid[len(grid) // 2])}
        col = design.column(name, nuisance)
        total = float(np.sum(col ** 2))
        if total < 1e-12:
            continue
        left = float(np.sum(_residualise(col, proj) ** 2)) / total
        if left < 1e-3:
            twins = [m for m in model if _max_corr(col, design.column(m, model[m])) > COLLINEAR]
            result.notes.append(f"{name} cannot be told apart from {', '.join(twins) or 'the model'}"
                                f" on this design: {RECORDS[name].separating_test}")
            if twins:
                _add_group(result.ambiguous, {name, *twins})
    spacing = np.diff(np.unique(design.x))
    if len(spacing) and "lead_error_periodic" not in model:
        _, low, high = RECORDS["lead_error_periodic"].nuisance["pitch_mm"]
        # pitches dividing every spacing: the periodic error has one phase at every target
        pitches = spacing[0] / np.arange(1, int(spacing[0] / low) + 1)
        pitches = pitches[(pitches >= low) & (pitches <= high)]
        aliased = [p for p in pitches if np.allclose(spacing / p, np.round(spacing / p), atol=1e-6)]
        if aliased:
            result.notes.append(
                "lead_error_periodic with a pitch of " + ", ".join(f"{p:g}" for p in aliased)
                + " mm is invisible at this target spacing on this design: "
                + RECORDS["lead_error_periodic"].separating_test)
            _add_group(result.ambiguous, {"lead_error_periodic"})


def _add_group(groups: list, members: set) -> None:
    """Add an ambiguous group, merging it with any group it shares an effect with."""
    for group in groups:
        if members & set(group):
            group[:] = sorted(members | set(group))
            return
    groups.append(sorted(members))


def residual_structure(design: Design, resid: np.ndarray) -> list[dict]:
    """How much of the residual each factor explains: the between-group share of the residual's
    sum of squares (adjusted for the number of groups) and its F-test p-value, strongest
    first. Continuous factors (time, temperature) are cut into five quantile bins."""
    from scipy.stats import f as f_dist

    factors = {"position": design.x, "direction": design.d,
               "position x direction": design.x * 10 + design.d,
               "run x position": design.run * 1e6 + design.x, "cycle": design.cycle}
    for name, key in (("time", "elapsed_s"), ("temperature", "machine_temp_c"),
                      ("feed", "feed_mm_min"), ("dwell", "dwell_s")):
        values = design.cond.get(key)
        if values is None or np.ptp(values) <= 0:
            continue
        if name in ("time", "temperature"):
            edges = np.unique(np.quantile(values, np.linspace(0, 1, 6)))
            values = np.digitize(values, edges[1:-1])
        factors[name] = values * 10 + design.d if name in ("feed", "dwell") else values
    n, total = len(resid), float(np.sum(resid ** 2))
    rows = []
    for name, values in factors.items():
        codes, groups = pd.factorize(values)
        g = len(groups)
        if g < 2 or g >= n - 1 or total <= 0:
            continue
        means = np.bincount(codes, resid) / np.bincount(codes)
        between = float(np.sum(np.bincount(codes) * means ** 2))
        within = total - between
        share = between / total
        adjusted = 1 - (1 - share) * (n - 1) / (n - g)
        p = float(f_dist.sf((between / (g - 1)) / max(within / (n - g), 1e-300), g - 1, n - g))
        rows.append({"against": name, "share": round(share, 4), "adjusted_share":
                     round(adjusted, 4), "p_value": p,
                     "rms_um": round(math.sqrt(between / n), 4)})
    return sorted(rows, key=lambda r: -r["adjusted_share"])


def _unexplained(design: Design, resid: np.ndarray, result: Discovery,
                 single_noise: bool) -> dict | None:
    """The remaining gap when it stays above the repeatability: its size and the residual's
    strongest structure, or the reason it is noise."""
    gap, noise = result.rmse_after_um, result.repeatability_um
    if not np.isfinite(noise) or noise <= 0 or gap <= STOP_RATIO * noise:
        return None
    structure = residual_structure(design, resid)
    level = STRUCTURE_P / max(len(structure), 1)
    significant = [s for s in structure if s["p_value"] < level]
    out = {"gap_um": gap, "repeatability_um": noise, "ratio": gap / noise,
           "structure": structure, "strongest": None, "verdict": "", "candidates": []}
    if single_noise or not significant:
        out["verdict"] = "noise-dominated"
        why = (f"the gap ({gap:.3g} um) is within {NOISE_RATIO:g}x the repeatability "
               f"({noise:.3g} um) of a single run" if single_noise else
               f"the residual shows no significant structure (F-test, p >= {level:.2g}) against "
               + ", ".join(s["against"] for s in structure))
        out["reason"] = f"noise-dominated: {why}; nothing to name"
    else:
        top = significant[0]
        column = FACTOR_INPUTS[top["against"]]
        out["strongest"] = top["against"]
        out["verdict"] = "structure"
        out["candidates"] = [n for n, r in RECORDS.items()
                             if (column in r.inputs or (column == "direction"
                                                        and r.kind == "lost_motion"))
                             and n not in result.named]
        out["reason"] = (f"the gap ({gap:.3g} um, {gap / noise:.1f}x the repeatability) is not "
                         f"explained: the residual varies most with {top['against']} "
                         f"({100 * top['share']:.0f} % of it, rms {top['rms_um']:.3g} um), and no "
                         "candidate passes")
    result.notes.append(out["reason"])
    return out
