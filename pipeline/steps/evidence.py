"""The evidence a fleet store holds beside an axis's laser visits: its trace days and ballbar
runs (``pipeline.store.records``, read through ``pipeline.steps.source.Source.records``), their
offsets to the laser's definition (``models.condition.evidence``), computed once per machine axis
(``axes_evidence``), and the series of all sources that ``drift`` analyses and ``fleet``
forecasts with.

A day measured twice (recorded again from another file, or re-measured) counts once: the
latest recorded trace record per day, the latest ballbar record per day, plane, visit,
radius and feed.
"""

from __future__ import annotations

import datetime as dt

import pandas as pd

from features.readings.errors import InputError
from models.condition.evidence import EVIDENCE_COLUMNS, OFFSET_WINDOW_DAYS, SOURCES, offsets

# Days a source must share with the laser before a series (drift's, the fleet's forecast)
# leans on it: fewer pairs give an offset whose scatter (the Birge ratio) cannot be judged.
MIN_SHARED_DAYS = 3
# Per source: its value and uncertainty keys in the records and in ``fleet --json``.
KEYS = {"trace": ("lost_motion_um", "lost_motion_u_um"),
        "ballbar": ("backlash_um", "backlash_u_um")}


def evidence_frame(records: dict, key: tuple, as_of: dt.date | None = None) -> pd.DataFrame:
    """The trace days and ballbar runs of machine axis ``key`` in ``records`` (what
    ``pipeline.steps.source.Source.records`` read), up to the end of day ``as_of``:
    ``EVIDENCE_COLUMNS`` plus ``plane`` (ballbar), sorted by source and date."""
    rows = []
    for source, (value, u) in KEYS.items():
        latest = {}
        for r in records.get(source, {}).get(key, []):  # oldest first: the latest wins
            latest[(r["date"], r.get("plane"), r.get("visit"), r.get("radius_mm"),
                    r.get("feed_mm_min"))] = r
        for r in latest.values():
            if as_of is not None and dt.date.fromisoformat(r["date"]) > as_of:
                continue
            label = (f"trace {r['date']}" if source == "trace"
                     else f"ballbar {r['plane']} {r['visit']}")
            rows.append({"source": source, "date": _noon(r["date"]), "value_um": r[value],
                         "u_um": r[u], "label": label, "plane": r.get("plane")})
    frame = pd.DataFrame(rows, columns=[*EVIDENCE_COLUMNS, "plane"])
    return frame.sort_values(["source", "date"], kind="stable").reset_index(drop=True)


def _noon(day: str) -> pd.Timestamp:
    """The middle of a recorded day (UTC): a day's points lie between its laser tests'
    morning and the next day's."""
    return pd.Timestamp(day, tz="UTC") + pd.Timedelta(hours=12)


def laser_frame(visits: pd.DataFrame) -> pd.DataFrame:
    """An axis's laser visits as ``models.condition.evidence.offset`` reads them."""
    return pd.DataFrame({"date": visits["date"].to_numpy(),
                         "value_um": visits["backlash_um"].to_numpy(float),
                         "u_um": visits["backlash_u_um"].to_numpy(float)})


def few_days_note(key: tuple, source: str, days: int, min_days: int = MIN_SHARED_DAYS) -> str:
    """The note of a machine axis whose ``source`` shares too few days with its laser visits
    for its series to lean on it."""
    return (f"{key[0]} axis {key[1]}: its {source} days share {days} day(s) with its laser "
            f"visits, fewer than {min_days}: its series uses the laser visits alone")


def axis_offsets(visits: pd.DataFrame, evidence: pd.DataFrame) -> tuple[dict, list[str]]:
    """The offset of each source with points to the axis's laser visits, and a note per
    source without a laser visit within ``OFFSET_WINDOW_DAYS`` of any of its points."""
    found = offsets(laser_frame(visits), evidence)
    first = visits.iloc[0]
    notes = [f"{first['machine_id']} axis {first['axis']}: no {s} point within "
             f"{OFFSET_WINDOW_DAYS:g} days of a laser visit; its offset to the laser cannot be "
             "estimated and its points stay out of the laser's series"
             for s, off in found.items() if off is None]
    return found, notes


def evidence_json(evidence: pd.DataFrame, found: dict) -> dict:
    """``evidence`` and ``offsets_um`` of an axis in ``fleet --json`` (docs/fleet.md)."""
    def points(source):
        value, u = KEYS[source]
        mine = evidence[evidence["source"] == source]
        return [{"date": r.date.date().isoformat(), value: _r(r.value_um), u: _r(r.u_um),
                 **({"plane": r.plane} if source == "ballbar" else {})}
                for r in mine.itertuples()]

    return {"evidence": {s: points(s) for s in KEYS},
            "offsets_um": {s: None if found.get(s) is None else {
                "value": _r(found[s]["value"]), "u": _r(found[s]["u"]),
                "days_in_common": found[s]["days_in_common"]} for s in KEYS}}


def _r(value) -> float:
    return round(float(value), 4)


def sources_of(evidence, parameter: str = "evidence") -> tuple[str, ...]:
    """The sources named by ``evidence`` (``"laser,trace"``, ``"all"`` or a list), in
    ``SOURCES`` order; the laser always among them (the others are shifted onto it)."""
    names = (SOURCES if evidence == "all" else
             [s.strip() for s in evidence.split(",")] if isinstance(evidence, str)
             else list(evidence))
    unknown = [s for s in names if s not in SOURCES]
    if unknown or not names:
        raise InputError(f"names {', '.join(map(repr, unknown)) or 'no source'}; expected "
                         f"'all' or some of {', '.join(SOURCES)}", parameter=parameter)
    return tuple(s for s in SOURCES if s in names or s == "laser")


def axes_evidence(visits: pd.DataFrame, records: dict, as_of=None) -> dict[tuple, tuple]:
    """Per machine axis of ``visits`` (its laser visits, ``visit_backlash`` rows): its other
    sources' points up to ``as_of`` (``evidence_frame``), their offsets to its laser visits and
    the notes of sources without one (``axis_offsets``), computed once for every reader:
    {(machine_id, axis): (frame, offsets, notes)}."""
    from features.visits import SERIES_KEYS

    out = {}
    for key, group in visits.groupby(list(SERIES_KEYS), sort=True, observed=True):
        key = tuple(map(str, key))
        frame = evidence_frame(records, key, as_of)
        out[key] = (frame, *axis_offsets(group, frame))
    return out


def with_evidence(visits: pd.DataFrame, records: dict, sources: tuple, as_of=None,
                  coverage_factor: float | None = None,
                  min_days: int = MIN_SHARED_DAYS,
                  keeps=None, evidence: dict | None = None) -> tuple[pd.DataFrame, dict, list]:
    """The laser visits of every machine axis with the points of the other ``sources``
    shifted onto the laser's definition (``models.condition.evidence.combined``), the offsets per
    machine axis, and the notes of sources without one. With a budget's ``coverage_factor``
    a point of another source gets ``backlash_U_um`` = k u and ``backlash_u_visit_um`` = u
    (all of its uncertainty changes from day to day). A source sharing fewer than
    ``min_days`` days with the laser stays out of the axis's series, with a note; its offset
    is still returned. ``keeps(machine_id, axis)``: the axes whose notes are wanted (a
    selection's; default all). ``evidence``: what ``axes_evidence`` found for ``visits``,
    when computed already."""
    from features.visits import SERIES_KEYS
    from models.condition.evidence import combined

    evidence_of = axes_evidence(visits, records, as_of) if evidence is None else evidence
    frames, found_all, notes = [], {}, []
    for key, group in visits.groupby(list(SERIES_KEYS), sort=True, observed=True):
        key = tuple(map(str, key))
        frame, found, more = evidence_of[key]
        few = {s: o["days_in_common"] for s, o in found.items()
               if o is not None and s in sources and o["days_in_common"] < min_days}
        if keeps is None or keeps(*key):
            notes += more + [few_days_note(key, s, n, min_days) for s, n in few.items()]
        found_all[key] = found
        frames.append(combined(group, frame, {
            s: o for s, o in found.items() if o is not None and s not in few}, sources))
    out = pd.concat(frames, ignore_index=True)
    if coverage_factor is not None:
        other = out["source"] != "laser"
        out.loc[other, "backlash_u_visit_um"] = out.loc[other, "backlash_u_um"]
        out.loc[other, "backlash_U_um"] = coverage_factor * out.loc[other, "backlash_u_um"]
    return out, found_all, notes
