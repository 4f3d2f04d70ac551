"""Backlash evidence beside the laser visits: the lost motion of controller-trace days and the
backlash of circular (ballbar) tests, brought onto the laser's definition.

Each source measures the axis's lost motion its own way: the laser's backlash is the step
between approach directions at rest (docs/backlash.md); a trace's lost motion is the motor -
load difference in motion, which may hold elastic wind-up the laser does not see; a ballbar's
backlash is the step fitted to a circle, at its feed and radius. So each source ``s`` is taken
to read the laser's value plus a constant offset, estimated from the days both measured:

.. math:: \\hat\\delta_s = \\frac{\\sum_k w_k d_k}{\\sum_k w_k}, \\quad
    d_k = y_{s,k} - y_{L,k}, \\quad w_k = \\frac{1}{u_{s,k}^2 + u_{L,k}^2}

over the pairs ``k`` of a laser visit and the source's point nearest in time within
``OFFSET_WINDOW_DAYS`` (each point in one pair at most), with the standard uncertainty
:math:`u(\\hat\\delta_s) = (\\sum_k w_k)^{-1/2}` scaled by the Birge ratio
:math:`\\sqrt{\\chi^2/(n-1)}` when the pairs scatter more than their uncertainties say
(GUM 4.2; Birge 1932). A source with no pair has no offset and stays out of the laser's series.

Shifted by its offset, a point reads :math:`y - \\hat\\delta_s` with the uncertainty
:math:`\\sqrt{u^2 + u(\\hat\\delta_s)^2}`, and the series of all sources is analysed as one
(``models.condition.drift.analyse_series``): a trace sees an adjustment on the day it is made, months
before the next laser visit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# Days apart a laser visit and another source's point may be and still measure the same
# backlash: a week, short beside the months a backlash takes to wear measurably.
OFFSET_WINDOW_DAYS = 7.0
SOURCES = ("laser", "trace", "ballbar")
# The evidence frame: one row per point of a source other than the laser.
EVIDENCE_COLUMNS = ("source", "date", "value_um", "u_um", "label")


def pairs(laser_days: np.ndarray, other_days: np.ndarray,
          window_days: float = OFFSET_WINDOW_DAYS) -> list[tuple[int, int]]:
    """(laser index, other index) of the pairs closest in time, nearest first, each point in
    one pair at most, at most ``window_days`` apart; days as numbers [d]."""
    gaps = np.abs(np.subtract.outer(np.asarray(laser_days, float),
                                    np.asarray(other_days, float)))
    order = np.argsort(gaps, axis=None, kind="stable")
    used_l, used_o, out = set(), set(), []
    for i, j in zip(*np.unravel_index(order, gaps.shape)):
        if gaps[i, j] > window_days:
            break
        if i not in used_l and j not in used_o:
            used_l.add(i)
            used_o.add(j)
            out.append((int(i), int(j)))
    return sorted(out)


def offset(laser: pd.DataFrame, other: pd.DataFrame,
           window_days: float = OFFSET_WINDOW_DAYS) -> dict | None:
    """The offset [um] of a source to the laser (module docstring), or None without a pair.

    Parameters
    ----------
    laser, other : DataFrame
        ``date`` (datetime, UTC), ``value_um`` and ``u_um`` (standard uncertainty) [um].

    Returns
    -------
    dict or None
        ``value`` and ``u`` [um], ``days_in_common`` (pairs), ``birge_ratio``, ``pairs``
        (laser day, other day).
    """
    found = pairs(_days(laser["date"]), _days(other["date"]), window_days)
    if not found:
        return None
    i, j = (np.array(k) for k in zip(*found))
    d = other["value_um"].to_numpy(float)[j] - laser["value_um"].to_numpy(float)[i]
    var = other["u_um"].to_numpy(float)[j] ** 2 + laser["u_um"].to_numpy(float)[i] ** 2
    w = 1.0 / np.fmax(var, 1e-12)
    value = float(np.sum(w * d) / np.sum(w))
    birge = (float(np.sqrt(np.sum(w * (d - value) ** 2) / (len(d) - 1))) if len(d) > 1
             else 1.0)
    return {"value": value, "u": float(max(birge, 1.0) / np.sqrt(np.sum(w))),
            "days_in_common": len(d), "birge_ratio": birge,
            "pairs": [(_iso(laser["date"].iloc[a]), _iso(other["date"].iloc[b]))
                      for a, b in found]}


def offsets(laser: pd.DataFrame, evidence: pd.DataFrame,
            window_days: float = OFFSET_WINDOW_DAYS) -> dict[str, dict | None]:
    """The offset of each source of ``evidence`` (``EVIDENCE_COLUMNS``) to ``laser``."""
    return {s: offset(laser, evidence[evidence["source"] == s], window_days)
            for s in SOURCES[1:] if (evidence["source"] == s).any()}


def combined(visits: pd.DataFrame, evidence: pd.DataFrame, found: dict,
             sources=SOURCES) -> pd.DataFrame:
    """One machine axis's laser visits (``features.visits.visit_backlash`` rows) with the
    points of the other ``sources`` shifted onto the laser's definition by their offsets
    ``found`` (``offsets``); a source without an offset is left out. The rows get ``source``
    and, for the others, ``visit`` = their label; sorted by date."""
    first = visits.iloc[0]
    rows = [visits.assign(source="laser")]
    for s in sources:
        off = found.get(s)
        mine = evidence[evidence["source"] == s]
        if s == "laser" or off is None or mine.empty:
            continue
        rows.append(pd.DataFrame({
            "machine_id": first["machine_id"], "axis": first["axis"],
            "visit": mine["label"].to_numpy(), "date": mine["date"].to_numpy(),
            "backlash_um": mine["value_um"].to_numpy(float) - off["value"],
            "backlash_u_um": np.hypot(mine["u_um"].to_numpy(float), off["u"]), "source": s}))
    out = pd.concat(rows, ignore_index=True)
    return out.sort_values("date", kind="stable").reset_index(drop=True)


def _days(dates) -> np.ndarray:
    """Days since 1970 of each date (naive ones taken as UTC)."""
    t = pd.to_datetime(pd.Series(dates).reset_index(drop=True), utc=True)
    return (t - pd.Timestamp(0, tz="UTC")).dt.total_seconds().to_numpy() / 86400.0


def _iso(stamp) -> str:
    return pd.Timestamp(stamp).date().isoformat()
