"""Per-point backlash targets (docs/data-contract.md §3) from a readings table.

Two definitions, one row per backlash point (``PAIR_KEYS`` + ``target``):

- ``paper`` ([BacklashNN], section 2.2.2): for a linear and a pendulum test that are paired
  (same machine, axis, visit, feed, dwell and repeat), per direction d
  ``z_d = mean_pendulum_d - mean_linear_d`` and ``backlash_um = |z_down - z_up|``, interior
  targets only. With a direct measuring system (linear scale) the linear cycle hides lost motion
  except at its turn-around targets while the pendulum cycle, reaching every target right after
  a reversal, shows it; the difference of the two directions cancels anything common to both
  (thermal expansion between the two runs shifts z_up and z_down alike).
- ``iso``: ``backlash_um = |B_i|`` with B_i = mean_up - mean_down, the ISO 230-2 reversal
  value, averaged over the tests of the point. With an indirect system (rotary encoder) every
  approach carries the lost motion, so B_i = -b in every test and ``z`` is about 0: the paper's
  target would report no backlash at all.

``auto`` decides from the evidence: when linear tests show almost no reversal at interior targets
while their paired pendulum tests do, the system is direct and ``paper`` applies; otherwise
``iso``. The choice and its reason are in ``frame.attrs`` (``target_kind``, ``target_reason``).
``backlash_u_um`` is the standard uncertainty of each point from the tests' repeatability.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features import iso230
from features.readings import schema
from features.readings.errors import InputError

KINDS = ("auto", "paper", "iso")
POINT_KEYS = (*schema.PAIR_KEYS, "target")
# Linear tests whose interior reversal is below this share of the pendulum's: direct system.
DIRECT_RATIO = 0.5


def backlash_targets(readings: pd.DataFrame, kind: str = "auto") -> pd.DataFrame:
    """Backlash per point: ``POINT_KEYS``, ``backlash_um``, ``backlash_u_um``, ``started_at``,
    and ``z_up_um``/``z_down_um`` for the paper definition."""
    if kind not in KINDS:
        raise InputError(f"unknown target {kind!r}; expected one of {', '.join(KINDS)}",
                         parameter="kind")
    source = readings.attrs.get("source", "readings")
    stats = _with_pair_keys(iso230.per_target(readings))
    stats["interior"] = _interior(stats)
    linear, pendulum = (stats[stats["method"] == m] for m in schema.METHODS)
    reason = ""
    if kind == "auto":
        kind, reason = choose_kind(linear, pendulum)
    points = paper_points(linear, pendulum, source) if kind == "paper" else iso_points(stats)
    points = points.sort_values(list(POINT_KEYS), kind="stable").reset_index(drop=True)
    points.attrs.update(target_kind=kind, target_reason=reason or _DEFAULT_REASON[kind],
                        source=source)
    return points


_DEFAULT_REASON = {
    "paper": "paper target: pendulum minus linear per direction, interior targets",
    "iso": "ISO 230-2 reversal value |B_i| per target",
}


def choose_kind(linear: pd.DataFrame, pendulum: pd.DataFrame) -> tuple[str, str]:
    """``paper`` for a direct measuring system, ``iso`` otherwise, with the evidence."""
    if linear.empty or pendulum.empty:
        have = "pendulum" if linear.empty else "linear"
        return "iso", f"only {have} tests: ISO reversal value |B_i| per target"
    b_linear = float(linear.loc[linear["interior"], "B_i"].abs().median())
    b_pendulum = float(pendulum.loc[pendulum["interior"], "B_i"].abs().median())
    evidence = (f"median interior |B_i| {b_linear:.2f} in linear tests vs {b_pendulum:.2f} in "
                "pendulum tests")
    if b_linear < DIRECT_RATIO * b_pendulum:
        return "paper", (f"{evidence}: direct measuring system (linear scale), lost motion shows "
                         "only after the pendulum's reversals; paper target pendulum minus linear")
    return "iso", (f"{evidence}: indirect measuring system (rotary encoder), every approach carries "
                   "the lost motion; ISO reversal value |B_i|")


def paper_points(linear: pd.DataFrame, pendulum: pd.DataFrame, source: str) -> pd.DataFrame:
    """z per direction and |z_down - z_up| at the interior targets of paired tests."""
    keys = list(POINT_KEYS)
    _check_pairs(linear, pendulum, source)
    cols = [*keys, "test_id", "mean_up", "mean_down", "s_up", "s_down", "n_up", "n_down",
            "interior"] + (["started_at"] if "started_at" in linear else [])
    both = linear[cols].merge(pendulum[cols], on=keys, suffixes=("_lin", "_pend"))
    both = both[both["interior_lin"] & both["interior_pend"]]
    if both.empty:
        raise InputError("paired tests share no interior target; the paper target needs "
                         "at least 3 common targets", file=source)
    z_up = both["mean_up_pend"] - both["mean_up_lin"]
    z_down = both["mean_down_pend"] - both["mean_down_lin"]
    var = sum(both[f"s_{d}_{m}"] ** 2 / both[f"n_{d}_{m}"]
              for d in ("up", "down") for m in ("lin", "pend"))
    out = both[keys].assign(backlash_um=(z_down - z_up).abs(), backlash_u_um=np.sqrt(var),
                            z_up_um=z_up, z_down_um=z_down,
                            linear_test_id=both["test_id_lin"],
                            pendulum_test_id=both["test_id_pend"])
    if "started_at_lin" in both:
        out["started_at"] = both[["started_at_lin", "started_at_pend"]].min(axis=1)
    return out


def iso_points(stats: pd.DataFrame) -> pd.DataFrame:
    """|B_i| per point, averaged over the tests (linear and pendulum) that reached it."""
    keys = list(POINT_KEYS)
    per_test = stats.assign(reversal=-stats["B_i"],
                            var=stats["s_up"] ** 2 / stats["n_up"]
                            + stats["s_down"] ** 2 / stats["n_down"])
    grouped = per_test.groupby(keys, dropna=False, sort=False)
    out = pd.DataFrame({"reversal": grouped["reversal"].mean(),
                        "backlash_u_um": np.sqrt(grouped["var"].sum()) / grouped.size()})
    if "started_at" in per_test:
        out["started_at"] = grouped["started_at"].min()
    out = out.reset_index()
    out.insert(len(keys), "backlash_um", out.pop("reversal").abs())
    return out


def _check_pairs(linear: pd.DataFrame, pendulum: pd.DataFrame, source: str) -> None:
    """Every linear test needs exactly one pendulum partner, and the other way round."""
    pair = list(schema.PAIR_KEYS)
    for name, mine, other in (("linear", linear, pendulum), ("pendulum", pendulum, linear)):
        tests = mine.drop_duplicates("test_id")
        doubled = tests[tests.duplicated(pair, keep=False)]
        if not doubled.empty:
            ids = ", ".join(doubled["test_id"].astype(str).head(2))
            raise InputError(f"{name} tests {ids} share machine, axis, visit, feed, dwell and "
                             "repeat; give them different repeat numbers", file=source,
                             column="repeat")
        partner = tests[pair].merge(other[pair].drop_duplicates(), how="left", indicator=True)
        alone = tests.loc[(partner["_merge"] == "left_only").to_numpy(), "test_id"]
        if not alone.empty:
            raise InputError(f"unpaired {name} test {alone.iloc[0]!r}: no "
                             f"{'pendulum' if name == 'linear' else 'linear'} test with the same "
                             "machine_id, axis, visit, feed_mm_min, dwell_s and repeat (the paper "
                             "target needs both; the iso target uses the reversal value instead)",
                             file=source, column="test_id")


def _interior(stats: pd.DataFrame) -> pd.Series:
    """True except at each test's first and last target, where backlash is not reliable."""
    test = stats.groupby(list(schema.TEST_KEYS), sort=False)["target"]
    return (stats["target"] > test.transform("min")) & (stats["target"] < test.transform("max"))


def _with_pair_keys(frame: pd.DataFrame) -> pd.DataFrame:
    """Pairing keys the readings lack are equal for every test (NaN pairs with NaN)."""
    missing = {k: np.nan for k in schema.PAIR_KEYS if k not in frame}
    return frame.assign(**missing) if missing else frame
