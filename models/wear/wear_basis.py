"""What the wear map reads and the bases it builds along the axis: the input names, the
columns that name a machine axis, and the B-spline and per-target bases."""

from __future__ import annotations

import numpy as np
import pandas as pd

from features.readings.schema import AXIS_KEYS
from features.statistics import bspline_basis

POSITION = "target"
HOURS = "operating_hours"
GROUPS = AXIS_KEYS  # the columns that name a machine axis on a fleet
AXIS_INDEX = "__axis__"  # row -> machine axis index in a fleet's local frame
# the wear map's own record of the condition terms: input -> the effect whose unit-amplitude
# contribution is the term's column
CONDITIONS = {"feed_mm_min": ("backlash_feed", "k_um_per_m_min"),
              "machine_temp_c": ("backlash_temperature", "k_um_per_k")}


def spline_basis(x, lo: float, hi: float, n_control: int, degree: int = 3) -> np.ndarray:
    """Uniform clamped B-spline basis over [lo, hi] ([Mechta2022], eq. 4), shape (len(x),
    n_control); degree min(degree, n_control - 1); outside the range the end values hold."""
    t = np.clip((np.asarray(x, float) - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return bspline_basis(t, n_control, degree)


def target_basis(x, knots_mm) -> np.ndarray:
    """One value per target: hat functions on the training targets (piecewise linear between
    them, the end values held beyond), shape (len(x), len(knots))."""
    x = np.clip(np.asarray(x, float), knots_mm[0], knots_mm[-1])
    return np.column_stack([np.interp(x, knots_mm, np.eye(len(knots_mm))[j])
                            for j in range(len(knots_mm))])


def split_groups(X):
    """(labels, X without them): the (machine_id, axis) of every row when a DataFrame ``X``
    has both columns (labels is then an object array of pairs), else (None, X)."""
    if not isinstance(X, pd.DataFrame) or not set(GROUPS) <= set(map(str, X.columns)):
        return None, X
    labels = X[list(GROUPS)].astype(str).to_numpy(object)
    return labels, X.drop(columns=list(GROUPS))
