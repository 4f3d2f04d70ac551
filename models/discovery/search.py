"""The discovery loop: fit the baseline, try every candidate, name the winner, repeat."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features import iso230
from features.readings import schema
from features.readings.errors import InputError
from models.discovery.candidates import (
    LOST_MOTION_PROFILE,
    amplitude,
    candidates,
    column_start,
)
from models.discovery.design import Design, bic, lstsq_fit, rank, rmse, stack
from models.discovery.structure import (
    NOISE_RATIO,
    STOP_RATIO,
    confounding_notes,
    structured,
    structured_beyond,
    unexplained,
)
from models.discovery.system import measuring_system
from models.discovery.terms import (
    EFFECTS,
    PROFILES,
    control_counts,
    missing_inputs,
    nuisance_grid,
    repeatability_um,
)
from models.discovery.verdicts import (
    BOOT_MIN_RUNS,
    bootstrap,
    choose,
    clearance_first,
    nested,
    parameters,
)

DEFAULT_BASELINE = ("backlash", "lead_error_linear")
COMPENSATE_HINT = ("a compensation table can correct it: backlash compensate (pitch-error "
                   "and reversal tables per target)")


@dataclass
class Step:
    """One named effect: its parameters, the amplitude's bootstrap interval, the evidence
    (delta BIC, CV gain) and the gap [um] before and after it was added."""

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
    """What ``discover`` found: the named effects, the ambiguous groups, one ``Step`` per
    named effect, the gap [um] before and after, the repeatability and the notes."""

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
    measuring_system: dict | None = None           # the decision and its test
    unit: str = "um"                               # of every value: arcsec on a rotary axis

    def to_dict(self) -> dict:
        return {"named": self.named, "ambiguous": self.ambiguous,
                "steps": [s.__dict__ for s in self.steps],
                "rmse_before_um": self.rmse_before_um, "rmse_after_um": self.rmse_after_um,
                "repeatability_um": self.repeatability_um, "notes": self.notes,
                "unexplained": self.unexplained, "measuring_system": self.measuring_system,
                "unit": self.unit}


def discover(readings: pd.DataFrame, baseline=DEFAULT_BASELINE, max_steps: int = 4,
             random_state: int = 0, source: str = "readings") -> Discovery:
    """Name the effects the baseline is missing (see ``models.discovery``).

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``measured_at`` for time effects).
    baseline : str or sequence of str
        Effects of the simulation model (comma-separated text allowed).
    max_steps : int
        Effects named at most.
    random_state : int
        Seed of the bootstrap.
    source : str
        Name of the readings in errors.
    """
    baseline = check_baseline(baseline, source)
    flagged = iso230.outliers(readings).to_numpy()
    # one wild reading inflates the repeatability by its square: the floor, the stopping rule
    # and the noise verdict all use the readings the ISO step keeps
    result = Discovery(repeatability_um=repeatability_um(readings.loc[~flagged]),
                       unit=schema.unit_of(readings["axis"]))
    if flagged.any():
        result.notes.append(
            f"{int(flagged.sum())} reading(s) flagged as outliers by the ISO 230-2 step left "
            "out of the fit and of the repeatability")
    result.used = ~flagged
    kept = readings.loc[~flagged].reset_index(drop=True)
    design = Design(kept)
    skipped = _skipped(design, baseline, source, result)
    # a profile in the baseline is its general form at its finest (a compensation table per
    # target): its record's own control points are not fitted
    model = {name: ({"n_control": max(control_counts(design.x))} if name in PROFILES else {})
             for name in baseline}
    _choose_system(design, model, kept, result)
    X = stack(design, model)
    _, resid = lstsq_fit(X, design.y0)
    result.residual_before = resid
    result.rmse_before_um = rmse(resid, design, X)
    rng = np.random.default_rng(random_state)
    barred = set()  # general forms a named specific effect stood in for
    # a single run within twice its repeatability is noise, unless its own residual structure
    # test says otherwise
    single_noise = (design.n_runs == 1
                    and result.rmse_before_um <= NOISE_RATIO * result.repeatability_um
                    and not structured(design, resid))
    if design.n_runs == 1:
        result.notes.append("one run only: cross-validation leaves out one cycle at a time; "
                            "repeat the test (other feed, dwell or temperature) to separate "
                            "effects that act between runs")
    for _ in range(0 if single_noise else max_steps):
        rmse_now = rmse(resid, design, X)
        # within the repeatability: stop, unless the residual still varies with a factor no
        # effect of the model acts along (a slow drift inflates the floor itself)
        if (rmse_now <= STOP_RATIO * result.repeatability_um
                and not structured_beyond(design, resid, model)):
            break
        table = candidates(design, model, skipped, result.repeatability_um, barred)
        result.evidence.append(table.drop(columns=["family"], errors="ignore"))
        passing = clearance_first(table[table["passes"]])
        if passing.empty:
            break
        sse0 = float(np.sum(lstsq_fit(X, design.y0)[1] ** 2))
        winner, group, stand_in = choose(design, model, passing, sse0)
        if len(group) > 1:
            result.ambiguous.append(sorted(group))
            tests = sorted({EFFECTS[g].separating_test for g in group})
            result.notes.append(f"{', '.join(sorted(group))} explain the gap equally well on "
                                f"this design: {'; '.join(tests)}")
            break
        stable, interval = bootstrap(design, model, winner, passing, rng)
        if not stable:
            result.notes.append(f"{winner['effect']} not stable under bootstrap by "
                                f"{'run' if design.n_runs >= BOOT_MIN_RUNS else 'cycle'}; "
                                "not named")
            break
        name = winner["effect"]
        if stand_in:  # what is left is the shape difference, not another effect
            barred.update({stand_in, *(e for e in EFFECTS if nested(e, stand_in))})
            result.notes.append(
                f"{name} named rather than the general {stand_in} form, which fits slightly "
                f"better (the effect's shape differs a little from the record's): "
                f"{EFFECTS[name].separating_test}")
        model[name] = winner["nuisance"]
        _refit_nuisances(design, model, result)
        X = stack(design, model)
        coef, resid = lstsq_fit(X, design.y0)
        result.named.append(name)
        step = Step(name, parameters(design, model, name, coef, winner),
                    {winner["amplitude"]: interval}, float(winner["delta_bic"]),
                    float(winner["cv_gain"]), rmse_now, rmse(resid, design, X),
                    winner["not_identified"])
        result.steps.append(step)
        for key, info in step.not_identified.items():
            result.notes.append(f"{name} named, but its {key} is not identified by this design "
                                f"(any of {info['range'][0]:g}-{info['range'][1]:g} fits as "
                                f"well): {info['test']}")
        if name in PROFILES or "n_control" in winner["nuisance"] or name == LOST_MOTION_PROFILE:
            result.notes.append(f"{name} varies along the axis: {COMPENSATE_HINT}")
    result.residual_after = resid
    result.rmse_after_um = rmse(resid, design, X)
    confounding_notes(design, model, skipped, result)
    result.unexplained = unexplained(design, resid, result, single_noise)
    return result


def _refit_nuisances(design: Design, model: dict, result: Discovery) -> None:
    """Forward selection that re-fits: with a new effect in the model, each effect named
    before it gets its nuisance value again, the others held, since it was chosen while the
    new one was missing: a specific effect's searched value over its grid, a general form's
    number of control points by BIC. A changed value updates the model, the named step's
    parameters (at the current fit) and the notes."""
    n = len(design.y0)
    for step in result.steps:
        name, nuisance = step.effect, model[step.effect]
        if "n_control" in nuisance:
            key, grid = "n_control", list(control_counts(design.x))
        else:
            key, grid = nuisance_grid(name, design.x)
        if key is None or key not in nuisance or len(grid) < 2:
            continue
        score = {}
        for value in (nuisance[key], *grid):
            trial = {**model, name: {**nuisance, key: value}}
            X = stack(design, trial)
            score[value] = bic(float(np.sum(lstsq_fit(X, design.y0)[1] ** 2)), n, rank(X))
        best = min(score, key=score.get)
        if score[best] < score[nuisance[key]]:
            model[name] = {**nuisance, key: best}
            coef = lstsq_fit(stack(design, model), design.y0)[0]
            start = column_start(design, model, name)
            own = coef[start:start + design.column(name, model[name]).shape[1]]
            amp_key = next(iter(step.interval))
            amp, _ = amplitude(design, model, coef, name, model[name], own, 0.0)
            step.parameters = parameters(design, model, name, coef,
                                         {"nuisance": model[name], "amplitude": amp_key,
                                          "coef": amp})
            result.notes.append(f"{name}: {key} re-fitted to {best:g} with "
                                f"{list(model)[-1]} in the model")


def check_baseline(baseline, source: str = "readings") -> list[str]:
    """The baseline's effect names: known, distinct, at least one (errors name the parameter
    ``baseline``)."""
    names = [b.strip() for b in (baseline.split(",") if isinstance(baseline, str) else baseline)]
    if not any(names):
        raise InputError("empty; expected comma-separated effect names from "
                         f"{', '.join(EFFECTS)}", parameter="baseline")
    for name in names:
        if name not in EFFECTS:
            raise InputError(f"unknown effect {name!r}; expected names from "
                             f"{', '.join(EFFECTS)}", parameter="baseline")
    if len(set(names)) < len(names):
        raise InputError("an effect is listed twice", parameter="baseline")
    return names


def _skipped(design: Design, baseline: list, source: str, result: Discovery) -> dict:
    """Effects whose inputs the readings lack (a baseline effect among them is an error)."""
    skipped = {}
    for name in EFFECTS:
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


def _choose_system(design: Design, model: dict, readings: pd.DataFrame,
                   result: Discovery) -> None:
    """Indirect or direct measuring system, for the baseline and every candidate: from the
    interior reversal values of the linear tests (``models.discovery.system``); without them,
    whichever fits the baseline's lost motion better (they differ only where some readings do
    not follow a reversal)."""
    if design.reversal_flags.all():
        return  # every reading follows a reversal: both systems see the same lost motion
    test = measuring_system(readings)
    if test.system is not None:
        design.system = test.system
        result.measuring_system = test.to_dict()
        result.notes.append(test.note())
        return
    if not any(EFFECTS[m].kind == "lost_motion" for m in model):
        return
    sse = {}
    for system in ("indirect", "direct"):
        design.system = system
        sse[system] = float(np.sum(lstsq_fit(stack(design, model), design.y0)[1] ** 2))
    design.system = min(sse, key=sse.get)
    if design.system == "direct":
        result.notes.append("lost motion shows only on readings that follow a reversal: direct "
                            "measuring system (linear scale) assumed")
