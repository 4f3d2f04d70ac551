"""What to compensate, per machine and axis: the error of each approach direction along the axis.

From measured tests: the ISO 230-2 per-target means of the axis's latest visit (flagged outlier
readings left out), pooled over its linear tests (the standard's cycle; pendulum tests only when
there are no linear ones), weighted by the number of readings. From a trained predictor: its
backlash at the requested conditions, split symmetrically (mean_up = -b/2, mean_down = +b/2),
with no position error (a predictor of backlash knows nothing of the lead error).

Sign conventions (docs/data-contract.md): deviation x = measured - target; lost motion makes
B_i = mean_up - mean_down negative; the scalar backlash written to controllers is
b = max(0, -mean B_i), the mean lost motion. A correction is what the controller must add to
the commanded position: correction = -deviation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError

REVERSAL_ALPHA = 0.01  # significance of the reversal test: a false alarm once in 100 axes


@dataclass
class AxisProfile:
    machine_id: str
    axis: str
    target: np.ndarray          # [mm] (deg for rotary), ascending
    mean_up: np.ndarray         # [um] (arcsec), deviation approaching +
    mean_down: np.ndarray       # [um] (arcsec), deviation approaching -
    u_up: np.ndarray            # standard uncertainty of mean_up [um]
    u_down: np.ndarray
    source: str                 # "measured" or "predicted"
    notes: list = field(default_factory=list)
    at_hours: float | None = None  # operating hours [h] a wear map's forecast is for
    cycles: int | None = None      # runs per direction of one test (fewest at any target)
    # the axis's lost motion at that visit by its measuring system (docs/backlash.md) [um]:
    # what fleet and drift report; measured profiles only (a predictor's scalar is its lost
    # motion already)
    lost_motion_um: float | None = None

    @property
    def scale(self) -> float:
        """Deviation units per position unit (um per mm, arcsec per deg)."""
        return schema.deviation_scale(self.axis)

    @property
    def reversal(self) -> np.ndarray:
        return self.mean_up - self.mean_down

    @property
    def position_error(self) -> np.ndarray:
        """Bidirectional mean deviation [um]: what a one-table controller corrects."""
        return (self.mean_up + self.mean_down) / 2

    @property
    def backlash(self) -> float:
        """The reversal compensation [um] >= 0, the scalar a controller adds at each
        reversal: -mean B_i of the tests compensated (linear tests, the ISO 230-2 cycle). With
        a direct measuring system it is not the axis's lost motion (``lost_motion_um``)."""
        return max(0.0, -float(np.mean(self.reversal)))

    def reversal_variation(self, alpha: float = REVERSAL_ALPHA) -> dict:
        """Whether the reversal value varies along the axis by more than its uncertainty, so
        that no scalar backlash can compensate it.

        With u(B_i)^2 = u_up,i^2 + u_down,i^2 and weights w_i = 1 / u(B_i)^2, the statistic

            chi2 = sum_i w_i (B_i - B_w)^2,   B_w = sum_i w_i B_i / sum_i w_i

        follows a chi-square distribution with n - 1 degrees of freedom when B_i is one
        value everywhere (the reversal test of a constant against its mean); ``p`` below
        ``alpha`` says it is not.

        Returns
        -------
        dict
            ``chi2``, ``dof``, ``p``, ``direction_dependent`` (bool; None when untestable:
            fewer than two targets, or a target without an uncertainty, e.g. a predictor),
            ``scalar_um`` (the scalar backlash b [um]) and ``scalar_leaves_um``: the largest
            reversal value a scalar b leaves, max_i |B_i + b| [um].
        """
        from scipy import stats

        u = np.sqrt(self.u_up ** 2 + self.u_down ** 2)
        leaves = float(np.max(np.abs(self.reversal + self.backlash)))
        out = {"chi2": None, "dof": len(u) - 1, "p": None, "direction_dependent": None,
               "scalar_um": self.backlash, "scalar_leaves_um": leaves}
        if self.source != "measured" or len(u) < 2 or not np.all(np.isfinite(u) & (u > 0)):
            return out
        w = 1.0 / u ** 2
        mean = float(np.sum(w * self.reversal) / np.sum(w))
        chi2 = float(np.sum(w * (self.reversal - mean) ** 2))
        p = float(stats.chi2.sf(chi2, len(u) - 1))
        return {**out, "chi2": chi2, "p": p, "direction_dependent": bool(p < alpha)}

    @property
    def stem(self) -> str:
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(self.machine_id))
        return f"{safe}_{self.axis}"


def measured_profiles(readings: pd.DataFrame) -> list[AxisProfile]:
    """One profile per machine and axis from validated readings (see module docstring)."""
    from features import iso230
    from features.visits import axis_backlash

    flagged = iso230.outliers(readings)
    profiles = []
    for (machine, axis), part in readings.groupby(["machine_id", "axis"], sort=True):
        notes = []
        bad = flagged.loc[part.index]
        if bad.any():
            notes.append(f"{int(bad.sum())} flagged outlier reading(s) not used")
        part = part.loc[~bad]
        visit = latest_visit(part)
        if part["visit"].nunique() > 1:
            notes.append(f"latest visit {visit} used (of {part['visit'].nunique()})")
        part = part[part["visit"] == visit]
        per = iso230.per_target(part)  # once: the lost motion and the profile read it
        lost = axis_backlash(part, per)["backlash_um"]
        methods = set(part["method"])
        if "linear" in methods and len(methods) > 1:
            per = per[per["method"] == "linear"].reset_index(drop=True)
            notes.append("linear tests used (the ISO 230-2 cycle); pendulum tests left out")
        profiles.append(_pool(per, str(machine), str(axis), notes))
        profiles[-1].lost_motion_um = float(lost.iloc[0]) if len(lost) else None
    return profiles


def latest_visit(readings: pd.DataFrame) -> str:
    """The visit measured last: by ``started_at`` when known, else by its id (numerically when
    every id is a number, so that visit 10 follows visit 9)."""
    if "started_at" in readings and readings["started_at"].notna().all():
        return str(readings.groupby("visit")["started_at"].min().idxmax())
    visits = readings["visit"].unique()
    numeric = pd.to_numeric(pd.Series(visits), errors="coerce")
    if numeric.notna().all():
        return str(visits[int(numeric.to_numpy().argmax())])
    return str(max(visits))


def _pool(per: pd.DataFrame, machine: str, axis: str, notes: list) -> AxisProfile:
    """Pool per-test per-target means over tests, weighted by readings; combine uncertainties."""
    rows = []
    for target, g in per.groupby("target", sort=True):
        row = {"target": float(target)}
        for side in ("up", "down"):
            n = g[f"n_{side}"].to_numpy(float)
            mean = g[f"mean_{side}"].to_numpy(float)
            s = g[f"s_{side}"].to_numpy(float)
            row[f"mean_{side}"] = float(np.sum(n * mean) / np.sum(n))
            # within-test scatter of the pooled mean; between-test spread when it is larger
            u_within = np.sqrt(np.sum((n - 1) * s ** 2) / max(np.sum(n) - len(n), 1) / np.sum(n))
            u_between = np.std(mean, ddof=1) / np.sqrt(len(mean)) if len(mean) > 1 else 0.0
            row[f"u_{side}"] = float(max(u_within, u_between))
        rows.append(row)
    t = pd.DataFrame(rows)
    if len(per["test_id"].unique()) > 1:
        notes.append(f"{per['test_id'].nunique()} tests pooled")
    counts = per[["n_up", "n_down"]].to_numpy(float)
    cycles = int(counts[counts > 0].min()) if (counts > 0).any() else None
    return AxisProfile(machine, axis, t["target"].to_numpy(), t["mean_up"].to_numpy(),
                       t["mean_down"].to_numpy(), t["u_up"].to_numpy(), t["u_down"].to_numpy(),
                       "measured", notes, cycles=cycles)


def parse_conditions(conditions) -> dict[str, float]:
    """Conditions for a predictor: ``"feed_mm_min=500,machine_temp_c=21"`` or a mapping of
    readings-table condition names to numbers -> dict of floats.

    Raises
    ------
    InputError
        For a malformed item, an unknown name or a value that is not a number
        (``parameter="conditions"``).
    """
    if not conditions:
        return {}
    if isinstance(conditions, str):
        items = []
        for item in conditions.split(","):
            if "=" not in item:
                raise InputError(f"{item!r}: expected NAME=VALUE", parameter="conditions")
            items.append(tuple(p.strip() for p in item.split("=", 1)))
    else:
        items = [(str(name), value) for name, value in dict(conditions).items()]
    allowed = (*schema.NUMERIC_OPTIONAL,)
    out = {}
    for name, value in items:
        if name not in allowed:
            raise InputError(f"unknown condition {name!r}; expected one of {', '.join(allowed)}",
                             parameter="conditions")
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{name}={value!r} is not a number",
                             parameter="conditions") from None
    return out


def predicted_profile(model, conditions: dict, axis: str, spacing_mm: float | None,
                      key: tuple[str, str] | None = None, travel=None) -> AxisProfile:
    """A profile from a trained predictor at ``conditions`` over its training target range
    (``travel`` = (low, high) [mm] instead); ``key`` = (machine_id, axis) names the machine
    axis of a model that knows several (a fleet's wear map)."""
    features = list(model.feature_names_)
    ranges = model.input_ranges_
    if "target" not in ranges:
        raise InputError("the model has no 'target' input range; cannot choose positions",
                         parameter="data")
    low, high = (float(v) for v in (travel or ranges["target"]))
    step = spacing_mm or (high - low) / 10 or 1.0
    target = np.arange(low, high + step / 2, step)
    plan = pd.DataFrame({"target": target})
    if key is not None:
        plan.insert(0, "axis", key[1])
        plan.insert(0, "machine_id", key[0])
    notes = []
    for name in features:
        if name == "target":
            continue
        if name in conditions:
            plan[name] = conditions[name]
        elif model.training_inputs_ is not None and name in model.training_inputs_:
            plan[name] = float(model.training_inputs_[name].median())
            notes.append(f"{name} not given: training median {plan[name].iloc[0]:g} used")
        else:
            raise InputError(f"the model needs {name}; give its value", parameter="conditions")
    unused = sorted(set(conditions) - set(features))
    if unused:
        notes.append(f"conditions the model does not use: {', '.join(unused)}")
    b = np.maximum(np.asarray(model.predict(plan), float), 0.0)
    u = np.full_like(b, float(model.validation_rmse_) / 2 if np.isfinite(
        model.validation_rmse_) else np.nan)
    notes.append(f"predicted by {model.name}: backlash only, no position error")
    machine, axis = key or (model.meta.get("machine_id", model.name), axis)
    hours = conditions.get("operating_hours") if "operating_hours" in features else None
    return AxisProfile(machine, axis, target, -b / 2, b / 2, u, u, "predicted", notes, hours)


# --------------------------------------------------------------------------- resampling


def nice_step(step: float) -> float:
    """The largest of 1, 2, 2.5, 5 x 10^k not above ``step``."""
    exponent = np.floor(np.log10(step))
    for mantissa in (5.0, 2.5, 2.0, 1.0):
        if mantissa * 10 ** exponent <= step * (1 + 1e-9):
            return float(mantissa * 10 ** exponent)
    return float(10 ** exponent)


def grid(target: np.ndarray, spacing: float | None, max_points: int) -> np.ndarray:
    """Equidistant points covering the targets. Default: equidistant targets are used as they
    are; otherwise a quarter of the smallest target interval rounded down to a nice step, from a
    multiple of it. A given ``spacing`` starts at a multiple of itself."""
    low, high = float(target.min()), float(target.max())
    steps = np.diff(target)
    if spacing is None and len(steps) and np.allclose(steps, steps[0], rtol=0, atol=1e-9):
        start, spacing = low, float(steps[0])
    else:
        if spacing is None:
            spacing = nice_step(float(np.min(steps)) / 4) if len(steps) else 1.0
        if spacing <= 0:
            raise InputError("must be > 0", parameter="spacing")
        start = np.floor(low / spacing + 1e-9) * spacing
    n = int(np.ceil((high - start) / spacing - 1e-9)) + 1
    if n > max_points:
        raise InputError(f"{n} points at {spacing:g} mm spacing; this controller takes at most "
                         f"{max_points}: choose a larger spacing", parameter="spacing")
    return start + spacing * np.arange(n)


def resample(target: np.ndarray, values: np.ndarray, points: np.ndarray
             ) -> tuple[np.ndarray, float]:
    """Values at ``points`` by linear interpolation (end values held), and the interpolation
    error at the measured targets [same unit]: max |table interpolated back - measured|."""
    table = np.interp(points, target, values)
    back = np.interp(target, points, table)
    return table, float(np.max(np.abs(back - values)))
