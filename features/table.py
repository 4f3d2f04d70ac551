"""Feature table: the backlash paper's Table 2 inputs per paired interior point, plus target.

One row per backlash point (``features.targets.backlash_targets``): the pair of tests
(``features.readings.schema.PAIR_KEYS``) and the target position. Inputs, as in the paper ([BacklashNN],
section 4, Table 2 and Fig. 9):

==================  ====================================================================
``target``          programmed position P_i [mm]
``deviation_down_um``  mean deviation of the linear test approached in the - direction [um]
``deviation_up_um``    mean deviation of the linear test approached in the + direction [um]
``feed_mm_min``     feed rate of the run [mm/min]
``machine_temp_c``  machine (ball screw) temperature, mean at that target [degC]
``ambient_temp_c``  air temperature, mean at that target [degC]
``pressure_hpa``    air pressure, mean at that target [hPa]
``humidity_pct``    relative humidity, mean at that target [%RH]
==================  ====================================================================

The conditions are means over the readings of the tests that show the backlash: for a
``paper`` point (pendulum minus linear in a direct system, where only the pendulum test
reverses at interior targets) the pendulum test's readings, for an ``iso`` point both tests;
each point by its own ``target_kind`` (with ``auto`` a fleet may hold both).
The two tests of a pair start at different temperatures; averaging them would mix the
pendulum's screw temperature, which sets the measured lost motion, with the linear test's,
which does not enter it.

plus ``dwell_s`` and ``operating_hours`` when the readings have them. The deviations come
from the linear test only, so a model trained on this table predicts what the pendulum test
would add from a linear test and its conditions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError, note

PAPER_FEATURES = ("target", "deviation_down_um", "deviation_up_um", "feed_mm_min",
                  "machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct")
EXTRA_FEATURES = ("dwell_s", "operating_hours")
ENVIRONMENT = ("machine_temp_c", "ambient_temp_c", "pressure_hpa", "humidity_pct",
               "operating_hours")
POINT_KEYS = (*schema.PAIR_KEYS, "target")
# The tests whose readings give a point's conditions, by its target kind (None: both tests).
CONDITION_METHODS = {"paper": ("pendulum",), "iso": None}


@dataclass
class FeatureTable:
    """Inputs ``X``, target ``y`` [um] and ``meta`` (point keys, date, the point's
    ``target_kind``) aligned row by row; ``target_kind`` of the table is 'paper', 'iso' or
    'mixed' (axes with different definitions). ``earlier``: rows set aside from this
    table that a model may still learn from but is never scored on (the visits before an
    adjustment that left the hour counter running on). ``auto_points``: the backlash points
    as ``features.targets.targets_of(stats, "auto")`` gave them, when the table was built from
    those (the per-visit series reuses them instead of computing them again)."""

    X: pd.DataFrame
    y: pd.Series
    meta: pd.DataFrame
    target_kind: str
    reason: str = ""
    earlier: FeatureTable | None = None
    auto_points: pd.DataFrame | None = field(default=None, repr=False)


def default_features(readings: pd.DataFrame, kind: str = "paper") -> list[str]:
    """The paper's eight inputs that the data can supply, plus dwell and operating hours.

    With the ``iso`` target (and a ``mixed`` table, whose iso points are the same) the two
    deviation inputs are left out: the reversal value is their difference, so they would hand
    the answer to the model.
    """
    available = {"target", *readings.columns}
    iso = kind in ("iso", "mixed")
    if not iso:
        available |= {"deviation_down_um", "deviation_up_um"}
    names = [f for f in (*PAPER_FEATURES, *EXTRA_FEATURES) if f in available]
    missing = [f for f in PAPER_FEATURES if f not in names]
    if missing:
        why = ""
        if iso:
            some = "" if kind == "iso" else " on some machine axes"
            why = f" (ISO target{some}: the reversal value is their difference)"
        note(f"inputs without {', '.join(missing)}{why}")
    return names


def feature_table(readings: pd.DataFrame, target: str = "auto",
                  features: list[str] | None = None,
                  stats: pd.DataFrame | None = None) -> FeatureTable:
    """Build the model table from a validated readings frame.

    Parameters
    ----------
    readings : DataFrame
        Validated readings (``features.readings.read_readings``).
    target : {'paper', 'iso', 'auto', 'mixed'}
        Backlash definition, see ``features.targets.backlash_targets``; 'mixed' (the kind of
        a table whose axes use different definitions, as a trained model records it) chooses
        per machine axis like 'auto'.
    features : list of str, optional
        Input columns; default ``default_features(readings)``. Unknown names are an error.
    stats : DataFrame, optional
        ``features.iso230.per_target(readings)`` when already computed.
    """
    from features.targets import MIXED, backlash_targets

    source = readings.attrs.get("source", "readings")
    readings = with_pair_keys(readings)
    points = backlash_targets(readings, kind="auto" if target == MIXED else target, stats=stats)
    kind = points.attrs["target_kind"]
    names = list(features) if features else default_features(readings, kind)
    table = with_inputs(points, readings)
    unknown = [f for f in names if f not in table.columns]
    if unknown:
        raise InputError(f"unknown feature {unknown[0]!r}; available: "
                         f"{', '.join(c for c in table.columns if c in _candidates(table))}",
                         file=source, parameter="features")
    table = table.sort_values(list(POINT_KEYS), kind="stable").reset_index(drop=True)
    if not features:
        constant = [n for n in names if table[n].nunique(dropna=False) < 2]
        if constant:
            note(f"{', '.join(constant)} constant over all points; left out")
            names = [n for n in names if n not in constant]
    meta_cols = [c for c in (*POINT_KEYS, "started_at", "direction", "target_kind")
                 if c in table]
    return FeatureTable(table[names].astype(float), table["backlash_um"].astype(float),
                        table[meta_cols], kind, points.attrs.get("target_reason", ""),
                        auto_points=points if target in ("auto", MIXED) else None)


def prediction_inputs(readings: pd.DataFrame, features: list[str]) -> pd.DataFrame:
    """Model inputs at every interior target of the readings' tests, no backlash needed.

    Returns ``POINT_KEYS`` plus ``features``, one row per point; linear tests supply the
    deviation inputs, so a model can predict backlash from a linear test and its conditions.
    """
    source = readings.attrs.get("source", "readings")
    readings = with_pair_keys(readings)
    extent = readings.groupby(list(schema.TEST_KEYS))["target"].agg(["min", "max"])
    bounds = extent.loc[pd.MultiIndex.from_frame(readings[list(schema.TEST_KEYS)])].to_numpy()
    interior = readings[(readings["target"] > bounds[:, 0]) & (readings["target"] < bounds[:, 1])]
    inputs = point_inputs(interior)
    missing = [f for f in features if f not in inputs]
    if missing:
        raise InputError(f"the model needs input {missing[0]!r}, which the readings lack",
                         file=source, column=missing[0])
    table = inputs[list(dict.fromkeys([*POINT_KEYS, *features]))]
    check_features(table[features], source, allow_constant=True, parameter=None)
    return table.sort_values(list(POINT_KEYS), kind="stable").reset_index(drop=True)


def with_inputs(points: pd.DataFrame, readings: pd.DataFrame) -> pd.DataFrame:
    """Points joined with their inputs (``point_inputs``), each point's conditions from the
    tests its ``target_kind`` uses (``CONDITION_METHODS``)."""
    keys = list(POINT_KEYS)

    def inputs(methods):  # the point's own columns (its date) win over the inputs'
        found = point_inputs(readings, methods)
        return found.drop(columns=[c for c in found if c in points and c not in keys])

    parts = [group.merge(inputs(CONDITION_METHODS[kind]), on=keys, how="left",
                         validate="many_to_one")
             for kind, group in points.groupby("target_kind", sort=True)]
    if len(parts) == 1:
        return parts[0]
    if not parts:
        return points.merge(inputs(None), on=keys, how="left", validate="many_to_one")
    return pd.concat(parts, ignore_index=True)


def with_pair_keys(readings: pd.DataFrame) -> pd.DataFrame:
    """Pairing keys that the readings lack are treated as equal for every test (NaN)."""
    missing = {k: np.nan for k in schema.PAIR_KEYS if k not in readings}
    return readings.assign(**missing) if missing else readings


def point_inputs(readings: pd.DataFrame, methods: tuple[str, ...] | None = None) -> pd.DataFrame:
    """Per point: linear-test mean deviation per direction, and mean conditions at that target
    over the readings of the tests in ``methods`` (default both tests of the pair; a point
    without such readings falls back to both)."""
    keys = list(POINT_KEYS)
    # rows are selected from the columns used only: copying the others (text among them)
    # would cost more than the grouping itself
    linear = readings.loc[readings["method"] == "linear", [*keys, "direction", "deviation_um"]]
    deviation = (linear.groupby([*keys, "direction"], dropna=False)["deviation_um"].mean()
                 .unstack("direction")
                 .rename(columns={"+": "deviation_up_um", "-": "deviation_down_um"}))
    env = [c for c in ENVIRONMENT if c in readings]
    inputs = deviation
    points = readings.groupby(keys, dropna=False)  # grouped once: both uses share the codes
    if env:
        conditions = points[env].mean()
        if methods:
            chosen = readings.loc[readings["method"].isin(methods), [*keys, *env]]
            conditions = (chosen.groupby(keys, dropna=False)[env].mean()
                          .combine_first(conditions))
        inputs = inputs.join(conditions, how="left")
    if "started_at" in readings:
        inputs = inputs.join(points["started_at"].min(), how="left")
    return inputs.reset_index()


def check_features(X: pd.DataFrame, source: str = "features", allow_constant: bool = False,
                   parameter: str | None = "features", meta: pd.DataFrame | None = None,
                   readings: pd.DataFrame | None = None) -> None:
    """Refuse inputs a network cannot learn from: NaN values and (for training) constant
    columns. ``parameter`` names the caller's parameter that chose the inputs (None when the
    inputs are a fitted model's, not the caller's choice). With the table's ``meta`` (its
    point keys, row by row) a NaN names the point's machine, axis, visit and target, and with
    the ``readings`` also the tests it comes from (``point_tests``)."""
    if X.empty:
        raise InputError("no backlash points: nothing to train on", file=source)
    remedy = " (leave it out of the features)" if parameter else ""
    nan = X.isna()
    if nan.any().any():
        col = nan.any().idxmax()
        rows = np.flatnonzero(nan[col].to_numpy())
        row = int(rows[0])
        where = "" if meta is None else f": {point_name(meta.iloc[row], col, readings)}"
        count = f"{len(rows)} points of the feature table, the first" if len(rows) > 1 else \
            "the feature table"
        raise InputError(f"NaN in feature at {count} point {row + 1}{where}; every input needs "
                         f"a value{remedy}", file=source, column=col, parameter=parameter)
    constant = [] if allow_constant else [c for c in X.columns if X[c].nunique() < 2]
    if constant:
        raise InputError(f"feature is constant ({X[constant[0]].iloc[0]:g}) over all points; "
                         f"it carries no information{remedy}", file=source,
                         column=constant[0], parameter=parameter)


def point_name(point: pd.Series, column: str, readings: pd.DataFrame | None = None) -> str:
    """A feature-table point for a message: ``machine M03, axis Y, visit 04, target 150`` and,
    with the readings, ``test T17`` (``point_tests``)."""
    parts = [f"{name} {point[key]:g}" if isinstance(point[key], float) else
             f"{name} {point[key]}"
             for key, name in (("machine_id", "machine"), ("axis", "axis"), ("visit", "visit"),
                               ("target", "target")) if key in point]
    tests = [] if readings is None else point_tests(readings, point, column)
    if tests:
        parts.append(f"test{'s' if len(tests) > 1 else ''} {', '.join(tests[:4])}"
                     + (" ..." if len(tests) > 4 else ""))
    return ", ".join(parts)


def point_tests(readings: pd.DataFrame, point: pd.Series, column: str) -> list[str]:
    """The ``test_id`` of the tests behind a feature-table ``point`` (its pair keys and
    target): those whose readings there lack ``column`` when the readings have it (a linear
    deviation: the linear tests), else every test of the point."""
    if "test_id" not in readings:
        return []
    keys = [k for k in POINT_KEYS if k in point.index and k in readings]
    here = np.ones(len(readings), bool)
    for key in keys:
        value, values = point[key], readings[key]
        here &= (values.isna() if pd.isna(value) else (values == value)).to_numpy(bool)
    found = readings[here]
    if column.startswith("deviation_") and "method" in found:
        found = found[found["method"] == "linear"]
    elif column in found and found[column].isna().any():
        found = found[found[column].isna()]
    return sorted(found["test_id"].astype(str).unique())


def _candidates(table: pd.DataFrame) -> list[str]:
    return [*PAPER_FEATURES, *EXTRA_FEATURES, *[c for c in table.columns if c.endswith("_c")]]
