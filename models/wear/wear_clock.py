"""The wear clock: which visits of a machine axis the wear map uses, and why.

A mechanical adjustment (re-preloading the nut, a new screw) restarts the wear: the operating
hours that drive wear count from the last adjustment. This module finds the adjustments
(events, hour counters that drop, or downward level changes the drift statistics find) and
keeps the visits since the last one of each machine axis.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd


def latest_epoch(meta: pd.DataFrame, hours: pd.Series | None = None,
                 events: pd.Series | None = None,
                 adjustments: pd.DataFrame | None = None) -> np.ndarray:
    """Rows since the last mechanical adjustment of their machine and axis (a boolean mask);
    see ``wear_epochs``, which also says why."""
    return wear_epochs(meta, hours, events, adjustments)[0]


def wear_epochs(meta: pd.DataFrame, hours: pd.Series | None = None,
                events: pd.Series | None = None, adjustments: pd.DataFrame | None = None):
    """Rows since the last mechanical adjustment of their machine and axis, and why.

    An adjustment restarts the wear clock: it shows as an ``event`` 'adjustment' (or 'reset')
    on a visit, as operating hours that drop from one visit to the next (visits in date order,
    else in natural label order), or as a visit listed in ``adjustments`` (``machine_id, axis,
    visit, reason``: the downward level changes that ``found_adjustments`` finds in the
    per-visit backlash), which finds adjustments that left the hour counter running.

    Returns
    -------
    mask : bool array, True for the rows kept
    notes : list of dicts, one per machine axis: ``machine_id, axis, visits`` (the visits
        kept, in order), ``dropped`` (number of earlier visits left out) and ``reason`` (what
        marked the start of the kept visits; empty when nothing did).
    """
    from models.estimators.evaluation import visit_order

    keep = np.ones(len(meta), bool)
    rank = visit_order(meta)
    labels = meta["visit"].astype(str).to_numpy() if "visit" in meta else rank.astype(str)
    axes = [c for c in ("machine_id", "axis") if c in meta]
    groups = meta.groupby(axes, dropna=False).indices if axes else {(): np.arange(len(meta))}
    found = {}
    if adjustments is not None:
        for row in adjustments.itertuples(index=False):
            found[(str(row.machine_id), str(row.axis), str(row.visit))] = row.reason
    notes = []
    for rows in groups.values():
        machine, axis = (str(meta[c].iloc[rows[0]]) if c in meta else "" for c in
                         ("machine_id", "axis"))
        order = rank[rows]
        visits = np.unique(order)
        start, why = visits[0], ""
        for previous, current in itertools.pairwise(visits):
            at = rows[order == current]
            before = rows[order == previous]
            reasons = []
            if events is not None:
                named = events.iloc[at].astype(str).str.lower()
                if named.isin(("adjustment", "reset")).any():
                    reasons.append(f"event '{named[named.isin(('adjustment', 'reset'))].iloc[0]}'")
            if hours is not None:
                now, then = float(hours.iloc[at].mean()), float(hours.iloc[before].mean())
                if now < then:
                    reasons.append(f"operating hours drop from {then:g} h to {now:g} h")
            change = found.get((machine, axis, str(labels[at[0]])))
            if change:
                reasons.append(change)
            if reasons:
                start, why = current, f"adjustment at visit {labels[at[0]]}: " + "; ".join(
                    reasons)
        keep[rows] = order >= start
        kept = [str(labels[rows[order == v][0]]) for v in visits if v >= start]
        notes.append({"machine_id": machine, "axis": axis, "visits": kept,
                      "dropped": int(np.sum(visits < start)), "reason": why})
    return keep, notes


def found_adjustments(visits: pd.DataFrame) -> pd.DataFrame:
    """Mechanical adjustments the drift statistics find in the per-visit backlash: downward
    level change points (``models.condition.drift.analyse_series``; an upward step is a failure, not an
    adjustment), the latest visit's drop included: a model trained after an adjustment learns
    from the visits since it only, however few.

    ``visits``: rows of ``features.visits.visit_backlash`` (``machine_id, axis, visit, date,
    backlash_um, backlash_u_um``). Returns ``machine_id, axis, visit, jump_um, jump_sigma, reason``.
    """
    from features.readings.schema import deviation_unit
    from models.condition import drift

    rows = []
    # two visits before a change at least; the last visit alone may follow one
    for series in drift.analyse_visits(visits, min_visits=3):
        for change in series.change_points:
            if change["jump_um"] < 0:
                visit = str(series.visits["visit"].iloc[change["index"]])
                rows.append({"machine_id": series.machine_id, "axis": series.axis,
                             "visit": visit, "jump_um": change["jump_um"],
                             "jump_sigma": change["jump_sigma"],
                             "reason": f"backlash steps down by {-change['jump_um']:.2f} "
                                       f"{deviation_unit(series.axis)} "
                                       f"({-change['jump_sigma']:.1f} sigma, drift change point)"})
    return pd.DataFrame(rows, columns=["machine_id", "axis", "visit", "jump_um", "jump_sigma",
                                       "reason"])


def epoch_lines(notes: list[dict], limit: int = 6) -> list[str]:
    """One human line per machine axis that says which visits the wear clock uses and why."""
    lines = []
    for note in notes[:limit]:
        name = " ".join(v for v in (note["machine_id"], note["axis"]) if v) or "data"
        visits = note["visits"]
        span = visits[0] if len(visits) == 1 else f"{visits[0]}..{visits[-1]}"
        why = (f"{note['reason']}; {note['dropped']} earlier visit(s) left out"
               if note["dropped"] else "no mechanical adjustment found")
        lines.append(f"wear clock {name}: visits {span} ({len(visits)}); {why}")
    if len(notes) > limit:
        lines.append(f"wear clock: {len(notes) - limit} more machine axes (model.json meta)")
    return lines


def usage_rates(readings: pd.DataFrame) -> list[dict]:
    """How fast each machine axis's hour counter runs: operating hours per calendar day.

    Per machine axis, each visit's date (its first ``started_at``) and hour-counter reading
    (median ``operating_hours``); the rate is the hours counted over the calendar days between
    consecutive visits, r = sum(dh) / sum(dd) over the pairs whose counter did not drop (a drop
    is a reset at an adjustment, not negative use).

    Returns
    -------
    list of dict
        ``machine_id, axis, last_date`` (ISO date of the last visit), ``last_hours`` [h] and
        ``hours_per_day`` [h/day], for the axes with two or more dated visits some days apart;
        empty when the readings have no ``started_at`` or ``operating_hours``.
    """
    from features.readings.schema import AXIS_KEYS

    if not {"started_at", "operating_hours", "visit", *AXIS_KEYS} <= set(readings.columns):
        return []
    visits = (readings.groupby([*AXIS_KEYS, "visit"], observed=True)
              .agg(date=("started_at", "min"), hours=("operating_hours", "median"))
              .dropna().reset_index().sort_values([*AXIS_KEYS, "date"]))
    rows = []
    for (machine, axis), v in visits.groupby(list(AXIS_KEYS), observed=True, sort=True):
        days = np.diff(v["date"].to_numpy("datetime64[s]")).astype(float) / 86400.0
        hours = np.diff(v["hours"].to_numpy(float))
        counted = (hours >= 0) & (days > 0)
        if not counted.any() or days[counted].sum() < 1:
            continue
        rows.append({"machine_id": str(machine), "axis": str(axis),
                     "last_date": pd.Timestamp(v["date"].iloc[-1]).date().isoformat(),
                     "last_hours": float(v["hours"].iloc[-1]),
                     "hours_per_day": round(float(hours[counted].sum() / days[counted].sum()), 6)})
    return rows
