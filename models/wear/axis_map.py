"""The wear-rate map of one machine axis since its last change point, as the fleet view shows
it: ``models.wear.wear_map.WearMap`` fitted on the axis's interior backlash points of the
visits since its last change point (``models.condition.drift``: an adjustment restarts the wear),

.. math:: b(x, h, f) = b_0(x) + w(x)\\, h / 1000 + k_f f / 1000

with x the target [mm, deg], h the operating hours [h] and, when it varies, the feed f
[mm/min]; the map is w(x) [unit per 1000 h] with its 95 % interval (``WearMap.wear_rate_map``).
When the map cannot be fitted the reason is returned instead.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# Visits since the last change point a wear-rate map needs.
MIN_WEAR_VISITS = 3


def axis_wear_map(points: pd.DataFrame | None, visits, hours: dict | None
                  ) -> tuple[dict | None, str]:
    """The wear-rate map of one axis, or (None, why).

    Parameters
    ----------
    points : DataFrame or None
        The axis's interior backlash points (``features.targets``): ``visit``, ``target``
        [mm or deg], ``feed_mm_min`` [mm/min], ``backlash_um`` [unit]; None: none.
    visits : iterable of str
        The visits since the axis's last change point.
    hours : dict or None
        The axis's operating hours [h] per visit; None: the readings carry none.

    Returns
    -------
    (dict or None, str)
        ``position_mm``, ``rate``, ``low``, ``high`` [unit per 1000 h] arrays, ``n_points``,
        ``visits`` (sorted) and ``n_control`` (the map's control points); and why there is no
        map (empty when there is one).
    """
    if hours is None:
        return None, "the readings carry no operating hours: no wear-rate map"
    kept = set(visits)
    if len(kept) < MIN_WEAR_VISITS:
        return None, (f"{len(kept)} visit(s) since the last change point; a wear-rate map needs "
                      f"{MIN_WEAR_VISITS}")
    points = points[points["visit"].astype(str).isin(kept)] if points is not None else None
    if points is None or points.empty:
        return None, "no interior backlash points since the last change point"
    X = pd.DataFrame({"target": points["target"].to_numpy(float),
                      "operating_hours": np.asarray(
                          [hours.get(str(v), np.nan) for v in points["visit"]], float)})
    if points["feed_mm_min"].nunique() > 1:
        X["feed_mm_min"] = points["feed_mm_min"].to_numpy(float)
    if X["operating_hours"].isna().any() or X["operating_hours"].nunique() < 2:
        return None, "operating hours missing or constant since the last change point"
    return _fitted(X, points["backlash_um"].to_numpy(float), sorted(kept)), ""


def _fitted(X: pd.DataFrame, y: np.ndarray, visits: list[str]) -> dict:
    from models.wear.wear_map import WearMap

    model = WearMap().fit(X, y)
    rate = model.wear_rate_map()
    return {"position_mm": rate["position_mm"].to_numpy(),
            "rate": rate["wear_rate_um_per_1000h"].to_numpy(),
            "low": rate["wear_rate_low"].to_numpy(), "high": rate["wear_rate_high"].to_numpy(),
            "n_points": len(y), "visits": visits, "n_control": str(model.n_control_)}
