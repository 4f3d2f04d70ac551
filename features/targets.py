"""Per-point backlash targets (docs/data-contract.md §3, docs/backlash.md) from a readings table.

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

``auto`` decides from the evidence, per machine axis (a fleet file mixes machines with a linear
scale and machines with a rotary encoder): when an axis's linear tests show almost no reversal at
interior targets while its pendulum tests do, its measuring system is direct and ``paper``
applies; otherwise ``iso`` (``axis_kinds``). A visit of a direct axis that has only linear or
only pendulum tests falls back to ``iso`` (the same rule for one test method). Every
point carries its ``target_kind``; ``frame.attrs["target_kind"]`` is ``"paper"`` or ``"iso"``
when all points agree and ``"mixed"`` otherwise, ``frame.attrs["target_reason"]`` says why.
``backlash_u_um`` is the standard uncertainty of each point from the tests' repeatability.
With an ISO/TR 230-9 budget (``features.uncertainty``) each point also carries ``backlash_U_um``,
the expanded uncertainty of its backlash (``point_uncertainty``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from features import iso230
from features import uncertainty as unc
from features.readings import schema
from features.readings.errors import InputError, note

KINDS = ("auto", "paper", "iso")
# Kind of a frame whose points use both definitions (different measuring systems per axis).
MIXED = "mixed"
POINT_KEYS = (*schema.PAIR_KEYS, "target")
AXIS_KEYS = schema.AXIS_KEYS
# Linear tests whose interior reversal is below this share of the pendulum's: direct system.
DIRECT_RATIO = 0.5
# Axes named in a reason before the rest are only counted.
NAMED_AXES = 4
# The two parts [um] of a point's budget uncertainty (``point_uncertainty``): systematic for one
# setup, and new at every run.
BUDGET_PARTS = ("backlash_u_setup_um", "backlash_u_env_um")


def backlash_targets(readings: pd.DataFrame, kind: str = "auto", budget=None,
                     stats: pd.DataFrame | None = None) -> pd.DataFrame:
    """Backlash per point of a readings table.

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``features.readings.read_readings``).
    kind : {'auto', 'paper', 'iso'}, default 'auto'
        Definition of a point's backlash; ``auto`` chooses per machine axis.
    budget : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget (``features.uncertainty``; e.g.
        ``experiments/data/paper_uncertainty.toml``): adds ``backlash_U_um``
        (``point_uncertainty``). Linear axes only.
    stats : DataFrame, optional
        ``features.iso230.per_target(readings)`` when already computed (a job computes it once
        and passes it down).

    Returns
    -------
    DataFrame
        One row per point: ``POINT_KEYS``, ``backlash_um`` [um], ``backlash_u_um`` [um],
        with a budget ``backlash_U_um`` [um] (k of the budget), ``target_kind`` ('paper' or
        'iso'), ``interior`` (not a test's first or last target), ``started_at`` (when the
        readings have it) and, for paper points, ``z_up_um``, ``z_down_um`` [um],
        ``linear_test_id`` and ``pendulum_test_id``. ``attrs`` hold ``target_kind`` ('paper',
        'iso' or 'mixed'), ``target_reason``, ``source`` and, with a budget,
        ``coverage_factor``.

    Raises
    ------
    InputError
        An unknown ``kind``, unpaired tests for ``paper``, an unreadable or non-physical
        budget, a budget for a rotary axis.
    """
    stats = iso230.per_target(readings) if stats is None else stats
    return targets_of(stats, kind, readings.attrs.get("source", "readings"), budget)


def targets_of(stats: pd.DataFrame, kind: str = "auto", source: str = "readings", budget=None,
               parts: bool = False) -> pd.DataFrame:
    """``backlash_targets`` from per-target statistics (``features.iso230.per_target``);
    with ``parts`` (and a budget) also the two parts ``BUDGET_PARTS`` [um] of each point's
    budget uncertainty (``point_uncertainty``), which the visit series combines."""
    if kind not in KINDS:
        raise InputError(f"unknown target {kind!r}; expected one of {', '.join(KINDS)}",
                         parameter="kind")
    budget = None if budget is None else unc.checked_budget(budget)
    stats = _with_pair_keys(stats).assign(interior=lambda s: _interior(s))
    if kind == "auto":
        points, reason = auto_points(stats, source)
    else:
        linear, pendulum = (stats[stats["method"] == m] for m in schema.METHODS)
        points = (paper_points(linear, pendulum, source) if kind == "paper"
                  else iso_points(stats)).assign(target_kind=kind)
        reason = _DEFAULT_REASON[kind]
    points = points.sort_values(list(POINT_KEYS), kind="stable").reset_index(drop=True)
    if budget is not None:
        points = point_uncertainty(points, stats, budget)
        if not parts:
            points = points.drop(columns=list(BUDGET_PARTS))
    kinds = points["target_kind"].unique()
    frame_kind = str(kinds[0]) if len(kinds) == 1 else MIXED if len(kinds) else "iso"
    points.attrs.update(target_kind=frame_kind, target_reason=reason, source=source)
    if budget is not None:
        points.attrs["coverage_factor"] = budget.coverage_factor
    return points


def point_uncertainty(points: pd.DataFrame, stats: pd.DataFrame,
                      budget: unc.UncertaintyBudget) -> pd.DataFrame:
    """``points`` with ``backlash_U_um``, the expanded uncertainty of each point's backlash,
    and its two budget parts ``BUDGET_PARTS``.

    Each test's reversal values B_i carry the budget's U(B) at the test's measuring length and
    runs per direction n (``features.uncertainty.per_test_um``), in two parts
    (``features.uncertainty.reversal_terms_um``): the setup's Abbe error u_setup = 2u_S, the
    same in every run of one setup, and the environmental variation u_env = 2u_EVE/√n, new in
    every run. The laser, misalignment and temperature errors, proportional to the position,
    are the same in the four means at one target and cancel in any difference of them.

    An ``iso`` point is the mean over the tests t that reached it of -B_i,t. Its parts are the
    largest of its tests' (with one setup the tests' errors are correlated, r ≤ 1, and the
    uncertainty of a mean is at most the largest of its terms, [GUM] 5.2.2):

    .. math:: u_{setup} = \\max_t 2u_S, \\qquad u_{env} = \\max_t 2u_{EVE}/\\sqrt{n_t}

    A ``paper`` point is |z_down - z_up| with z_d = (pendulum mean) - (linear mean), that is
    the difference of the two tests' reversal values, b = |B_lin - B_pend|. Both tests of a
    pair are made at one visit with one setup (same laser position, Abbe offset and direction of
    approach at the target): their Abbe errors are the same (r = +1) and cancel, as does a
    thermal change between the two runs, common to both directions. The environmental
    variations of the two runs are uncorrelated and add ([GUM] 5.1.2):

    .. math::

        u_{setup} = 0, \\qquad
        u_{env} = \\sqrt{\\frac{(2u_{EVE})^2}{n_{lin}} + \\frac{(2u_{EVE})^2}{n_{pend}}}

    With the point's repeatability u_r (``backlash_u_um``, a Type A evaluation from the
    readings' scatter; taken as 0 where the data give none), uncorrelated with both:

    .. math:: U = k \\sqrt{u_{setup}^2 + u_{env}^2 + u_r^2}

    For an ``iso`` point of one test this is k √((U(B)/k)² + u_r²), the form the visit series
    uses (``features.visits.axis_backlash``). With the paper's budget (Table 3, n = 5) U(B) =
    4.12 um, while a ``paper`` point's budget part is k·√2·2u_EVE/√5 = 0.73 um: its Abbe term
    cancels. A test with one target has no length to scale the budget to and takes the
    budget's own ``length_mm`` and ``cycles``.

    Parameters
    ----------
    points : DataFrame
        Backlash points (``targets_of``) with ``target_kind``, ``backlash_u_um`` and, for
        paper points, ``linear_test_id`` and ``pendulum_test_id``.
    stats : DataFrame
        The per-target statistics the points come from, with every ``POINT_KEYS`` column.
    budget : UncertaintyBudget
        The contributors and k.

    Returns
    -------
    DataFrame
        ``points`` plus ``backlash_U_um`` [um] (k of the budget) and ``BUDGET_PARTS`` [um].

    Raises
    ------
    InputError
        A test on a rotary axis (a budget holds lengths, not angles).

    References
    ----------
    .. [ISO230-9] ISO/TR 230-9:2005; the U(B) form of the backlash paper's Table 4
       (``features.uncertainty.expanded_parameters_um``).
    .. [GUM] JCGM 100:2008, 5.1.2 (uncorrelated inputs) and 5.2.2 (correlated inputs).
    """
    setup, env = unc.REVERSAL_PARTS
    tests = unc.per_test_um(stats, budget)
    for column, nominal in zip((setup, env), unc.nominal_reversal_parts_um(budget)):
        tests[column] = tests[column].fillna(nominal)
    test_keys = list(schema.TEST_KEYS)
    out = points.assign(**dict.fromkeys(BUDGET_PARTS, np.nan))
    paper = (out["target_kind"] == "paper").to_numpy()
    if paper.any():
        env_of = {}
        for method in schema.METHODS:
            ids = out.loc[paper, [*test_keys[:-1], f"{method}_test_id"]].rename(
                columns={f"{method}_test_id": "test_id"})
            env_of[method] = ids.merge(tests[[*test_keys, env]], on=test_keys,
                                       how="left")[env].to_numpy(float)
        out.loc[paper, BUDGET_PARTS[0]] = 0.0
        out.loc[paper, BUDGET_PARTS[1]] = np.hypot(*env_of.values())
    if (~paper).any():
        keys = list(POINT_KEYS)
        per_point = (stats[[*keys, "test_id"]].merge(tests[[*test_keys, setup, env]],
                                                     on=test_keys, how="left")
                     .groupby(keys, dropna=False, sort=False)[[setup, env]].max())
        found = out.loc[~paper, keys].merge(per_point.reset_index(), on=keys, how="left")
        out.loc[~paper, BUDGET_PARTS[0]] = found[setup].to_numpy(float)
        out.loc[~paper, BUDGET_PARTS[1]] = found[env].to_numpy(float)
    u_r = out["backlash_u_um"].fillna(0.0)
    u_budget = np.hypot(out[BUDGET_PARTS[0]], out[BUDGET_PARTS[1]])
    at = out.columns.get_loc("backlash_u_um") + 1
    out.insert(at, "backlash_U_um", budget.coverage_factor * np.hypot(u_budget, u_r))
    return out


_DEFAULT_REASON = {
    "paper": "paper target: pendulum minus linear per direction, interior targets",
    "iso": "ISO 230-2 reversal value |B_i| per target",
}
_KIND_TEXT = {
    "paper": "direct measuring system (linear scale): pendulum minus linear",
    "iso": "indirect measuring system (rotary encoder) or one test method: ISO reversal value "
           "|B_i|",
}


def _decide(b_linear: float, b_pendulum: float, has_linear: bool,
            has_pendulum: bool) -> tuple[str, str]:
    """The evidence rule: direct when |B_i| of linear tests < DIRECT_RATIO x pendulum's."""
    if not (has_linear and has_pendulum):
        have = "pendulum" if has_pendulum else "linear"
        return "iso", f"only {have} tests: ISO reversal value |B_i| per target"
    evidence = (f"median interior |B_i| {b_linear:.2f} in linear tests vs {b_pendulum:.2f} in "
                "pendulum tests")
    if b_linear < DIRECT_RATIO * b_pendulum:
        return "paper", (f"{evidence}: direct measuring system (linear scale), lost motion shows "
                         "only after the pendulum's reversals; paper target pendulum minus linear")
    return "iso", (f"{evidence}: indirect measuring system (rotary encoder), every approach carries "
                   "the lost motion; ISO reversal value |B_i|")


def axis_kinds(stats: pd.DataFrame) -> pd.DataFrame:
    """The definition of every machine axis by the evidence rule (``_decide``).

    Parameters
    ----------
    stats : DataFrame
        Per-target statistics of all tests with ``machine_id``, ``axis``, ``method``,
        ``B_i`` [um] and ``interior``.

    Returns
    -------
    DataFrame
        ``machine_id``, ``axis``, ``target_kind`` and ``target_reason``, one row per axis.
    """
    keys = list(AXIS_KEYS)
    counts = stats.groupby([*keys, "method"], observed=True).size().unstack("method")
    inner = stats[stats["interior"]]
    median = (inner.assign(abs_b=inner["B_i"].abs())
              .groupby([*keys, "method"], observed=True)["abs_b"].median().unstack("method"))
    methods = list(schema.METHODS)
    evidence = counts.reindex(columns=methods).fillna(0).join(
        median.reindex(columns=methods).add_suffix("_b"))
    rows = [(*axis, *_decide(row.linear_b, row.pendulum_b, row.linear > 0, row.pendulum > 0))
            for axis, row in zip(evidence.index, evidence.itertuples(index=False), strict=True)]
    return pd.DataFrame(rows, columns=[*keys, "target_kind", "target_reason"])


def auto_points(stats: pd.DataFrame, source: str = "readings") -> tuple[pd.DataFrame, str]:
    """Points of every machine axis by its own definition (``axis_kinds``), and the reason.

    A visit of a ``paper`` axis without a linear or without a pendulum test has no pair: its
    points fall back to ``iso``, as the evidence rule does for one test method.
    """
    keys, visit_keys = list(AXIS_KEYS), [*AXIS_KEYS, "visit"]
    kinds = axis_kinds(stats)
    kind = stats[keys].merge(kinds[[*keys, "target_kind"]], on=keys, how="left")["target_kind"]
    methods = stats.groupby(visit_keys, dropna=False, observed=True)["method"].transform("nunique")
    alone = (kind.to_numpy() == "paper") & (methods.to_numpy() < 2)
    kind = np.where(alone, "iso", kind.to_numpy())
    parts = []
    paper = stats[kind == "paper"]
    if not paper.empty:
        linear, pendulum = (paper[paper["method"] == m] for m in schema.METHODS)
        parts.append(paper_points(linear, pendulum, source).assign(target_kind="paper"))
    if (kind == "iso").any():
        parts.append(iso_points(stats[kind == "iso"]).assign(target_kind="iso"))
    fallback = stats[alone].drop_duplicates(visit_keys)
    _note_hidden(fallback)
    points = pd.concat(parts, ignore_index=True) if len(parts) > 1 else parts[0]
    return points, _reason(kinds, fallback)


def _note_hidden(fallback: pd.DataFrame) -> None:
    """Warn about visits of a direct axis measured with linear tests only."""
    hidden = fallback[fallback["method"] == "linear"]
    if not hidden.empty:
        note(f"{_names(hidden, with_visit=True)}: only linear tests on a direct measuring "
             "system, which hide lost motion except at the turn-around targets; the ISO reversal "
             "value |B_i| reads low there (add pendulum tests)")


def _reason(kinds: pd.DataFrame, fallback: pd.DataFrame) -> str:
    """One axis: its evidence; several: the axes per definition, briefly."""
    if len(kinds) == 1:
        reason = str(kinds["target_reason"].iloc[0])
    elif kinds["target_kind"].nunique() == 1:
        kind = kinds["target_kind"].iloc[0]
        reason = f"{kind} on every machine axis ({len(kinds)}): {_KIND_TEXT[kind]}"
    else:
        reason = "per machine axis: " + "; ".join(
            f"{kind} on {_names(group)} ({_KIND_TEXT[kind]})"
            for kind, group in kinds.groupby("target_kind", sort=True))
    if not fallback.empty:
        reason += (f"; iso at visits with one test method only ({_names(fallback, True)}): "
                   "no pendulum-linear pair")
    return reason


def _names(frame: pd.DataFrame, with_visit: bool = False) -> str:
    """'M01 X, M02 Y and 3 more' (with the visit: 'M01 X visit 03')."""
    names = [f"{r.machine_id} {r.axis}" + (f" visit {r.visit}" if with_visit else "")
             for r in frame.itertuples(index=False)]
    more = len(names) - NAMED_AXES
    return ", ".join(names[:NAMED_AXES]) + (f" and {more} more" if more > 0 else "")


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
                            pendulum_test_id=both["test_id_pend"], interior=True)
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
                        "backlash_u_um": np.sqrt(grouped["var"].sum()) / grouped.size(),
                        "interior": grouped["interior"].all()})
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
