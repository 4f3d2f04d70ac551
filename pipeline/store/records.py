"""What the store remembers besides readings: the forecasts made for a machine axis, the
compensations written to its controller, and the other evidence of its backlash: the lost
motion of each day of controller traces (``trace``, from ``monitor``) and the backlash of each
circular test (``ballbar``, from ``circle``).

A record is one JSON object per machine axis (a forecast: per visit it is for; a
compensation: per controller), checked field by field when it is made and again when it is
read back (``check_forecast``, ``check_compensation``), and named by the SHA-256 of its canonical text (``digest``): recording
the same content twice adds nothing. Both engines keep them in two tables of the same columns
(``machine_id``, ``axis``, ``sha256``, ``recorded_at``, ``record``) through ``Store.put_records``
and ``Store.get_records``, with the same SQL (``pipeline.store.tables``).

A job records its result through the recorder its record names (``Workflow.records``:
``record_forecast``, ``record_compensation``, ``record_trace``, ``record_ballbar``,
``record_probing``, ``record_stiffness``, each ``function(store, result)``); the runner opens
the store before the job runs and calls it, never the job itself.

>>> from pipeline.store.records import record_compensation, read_records   # doctest: +SKIP
>>> record_compensation("fleet/", bl.compensate("fleet/", controller="csv"))  # doctest: +SKIP
>>> read_records("fleet/", "compensation")[("M01", "X")][-1]["controller"]    # doctest: +SKIP
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
from dataclasses import dataclass

from features.readings import schema
from features.readings.errors import InputError
from pipeline.store.tables import now

# The record's own layout: part of every record, so a future change can never be misread.
RECORD_FORMAT = 1
AXES = (*schema.LINEAR_AXES, *schema.ROTARY_AXES)


@dataclass
class Recorded:
    """What one recording did: ``added`` new records, ``unchanged`` ones already stored."""

    kind: str
    added: int
    unchanged: int
    location: str

    @property
    def text(self) -> str:
        """One line for the command's summary."""
        noun = f"{self.kind} record" if self.kind.endswith("s") else self.kind  # stiffness
        what = f"{noun}{'s' if self.added != 1 else ''}"
        same = f" ({self.unchanged} already recorded)" if self.unchanged else ""
        return f"{self.added} {what} recorded in {self.location}{same}"


# --------------------------------------------------------------------------- content
def canonical(record: dict) -> str:
    """The record's text: keys sorted, no spaces, numbers as Python writes them (exact)."""
    return json.dumps(record, sort_keys=True, separators=(",", ":"), allow_nan=False,
                      ensure_ascii=False)


def digest(record: dict) -> str:
    return hashlib.sha256(canonical(record).encode("utf-8")).hexdigest()


def _fail(where: str, message: str):
    raise InputError(f"{message}; expected a {where}")


def _number(value, name: str, kind: str, optional: bool = False, minimum=None):
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value) or (minimum is not None and value < minimum):
        _fail(kind, f"{name} is {value!r}, not a finite number"
              + ("" if minimum is None else f" >= {minimum:g}"))
    return float(value)


def _text(value, name: str, kind: str, optional: bool = False):
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value.strip():
        _fail(kind, f"{name} is {value!r}, not a non-empty text")
    return value


def _numbers(values, name: str, kind: str, n: int | None, optional_items: bool = False,
             minimum=None) -> list:
    if not isinstance(values, list) or not values or (n is not None and len(values) != n):
        _fail(kind, f"{name} is not a list of {n or 'one or more'} numbers")
    return [_number(v, f"{name}[{i}]", kind, optional_items, minimum)
            for i, v in enumerate(values)]


def _date(value, name: str, kind: str):
    if value is None:
        return None
    try:
        dt.date.fromisoformat(value)
    except (TypeError, ValueError):
        _fail(kind, f"{name} is {value!r}, not a date YYYY-MM-DD")
    return value


def _head(record, kind: str, keys: set) -> None:
    if not isinstance(record, dict) or record.get("kind") != kind.split()[0]:
        _fail(kind, "the record is not a " + kind.split()[0])
    if record.get("format") != RECORD_FORMAT:
        _fail(kind, f"record format {record.get('format')!r} is not {RECORD_FORMAT}")
    unknown = sorted(set(record) - keys)
    if unknown:
        _fail(kind, f"unknown field(s) {', '.join(unknown)}")
    _text(record.get("machine_id"), "machine_id", kind)
    if record.get("axis") not in AXES:
        _fail(kind, f"axis is {record.get('axis')!r}, not one of {', '.join(AXES)}")


FORECAST_KEYS = {"kind", "format", "machine_id", "axis", "visit", "for_date", "operating_hours",
                 "model", "model_dir", "model_sha256", "points", "wear_rate"}
POINT_KEYS = ("target", "backlash_um", "backlash_low_um", "backlash_high_um", "operating_hours")
WEAR_KEYS = ("position_mm", "rate", "low", "high")
COMPENSATION_KEYS = {"kind", "format", "machine_id", "axis", "controller", "source", "unit",
                     "reversal_compensation_um", "table", "files", "interpolation_error_um"}
TABLE_KEYS = ("target", "error_up_um", "error_down_um")


def check_forecast(record) -> dict:
    """``record`` if it is a forecast this version can interpret, else one ``InputError``."""
    kind = "forecast record"
    _head(record, kind, FORECAST_KEYS)
    _text(record.get("visit"), "visit", kind, optional=True)
    _date(record.get("for_date"), "for_date", kind)
    _number(record.get("operating_hours"), "operating_hours", kind, optional=True, minimum=0)
    _text(record.get("model"), "model", kind)
    for key in ("model_dir", "model_sha256"):
        _text(record.get(key), key, kind, optional=True)
    points = record.get("points")
    if not isinstance(points, dict) or set(points) - set(POINT_KEYS) or not {
            "target", "backlash_um"} <= set(points):
        _fail(kind, "points must hold target and backlash_um lists (and optionally "
                    f"{', '.join(POINT_KEYS[2:])})")
    n = len(_numbers(points["target"], "points.target", kind, None))
    _numbers(points["backlash_um"], "points.backlash_um", kind, n, minimum=0)
    if ("backlash_low_um" in points) != ("backlash_high_um" in points):
        _fail(kind, "points give one bound of the interval only")
    for key in POINT_KEYS[2:]:
        if key in points:
            _numbers(points[key], f"points.{key}", kind, n, optional_items=key ==
                     "operating_hours")
    wear = record.get("wear_rate")
    if wear is not None:
        if not isinstance(wear, dict) or set(wear) != set(WEAR_KEYS):
            _fail(kind, f"wear_rate must hold {', '.join(WEAR_KEYS)}")
        m = len(_numbers(wear["position_mm"], "wear_rate.position_mm", kind, None))
        for key in WEAR_KEYS[1:]:
            _numbers(wear[key], f"wear_rate.{key}", kind, m, optional_items=True)
    return record


def check_compensation(record) -> dict:
    """``record`` if it is a compensation this version can interpret, else one
    ``InputError``."""
    kind = "compensation record"
    _head(record, kind, COMPENSATION_KEYS)
    _text(record.get("controller"), "controller", kind)
    if record.get("source") not in ("measured", "predicted"):
        _fail(kind, f"source is {record.get('source')!r}, not measured or predicted")
    if record.get("unit") != schema.deviation_unit(record["axis"]):
        _fail(kind, f"unit is {record.get('unit')!r}, not that of axis {record['axis']}")
    _number(record.get("reversal_compensation_um"), "reversal_compensation_um", kind,
            minimum=0)
    _number(record.get("interpolation_error_um"), "interpolation_error_um", kind, optional=True)
    table = record.get("table")
    if not isinstance(table, dict) or set(table) != set(TABLE_KEYS):
        _fail(kind, f"table must hold {', '.join(TABLE_KEYS)}")
    n = len(_numbers(table["target"], "table.target", kind, None))
    if any(b <= a for a, b in zip(table["target"], table["target"][1:])):
        _fail(kind, "table.target is not ascending")
    for key in TABLE_KEYS[1:]:
        _numbers(table[key], f"table.{key}", kind, n)
    files = record.get("files")
    if not isinstance(files, list) or not all(isinstance(f, str) and f for f in files):
        _fail(kind, "files is not a list of file names")
    return record


TRACE_KEYS = {"kind", "format", "machine_id", "axis", "date", "lost_motion_um",
              "lost_motion_u_um", "reversals", "source",
              "samples_expected", "samples_received", "coverage"}  # the last three: watch's gap
BALLBAR_KEYS = {"kind", "format", "machine_id", "axis", "date", "plane", "visit", "radius_mm",
                "feed_mm_min", "backlash_um", "backlash_u_um", "source"}


def check_trace(record) -> dict:
    """``record`` if it is a trace day (one machine axis's lost motion on one day, from
    ``monitor``) this version can interpret, else one ``InputError``."""
    kind = "trace record"
    _head(record, kind, TRACE_KEYS)
    if _date(record.get("date"), "date", kind) is None:
        _fail(kind, "date is missing")
    _number(record.get("lost_motion_um"), "lost_motion_um", kind)
    _number(record.get("lost_motion_u_um"), "lost_motion_u_um", kind, minimum=0)
    _number(record.get("reversals"), "reversals", kind, minimum=0)
    _text(record.get("source"), "source", kind)
    for key in ("samples_expected", "samples_received", "coverage"):
        _number(record.get(key), key, kind, optional=True, minimum=0)
    return record


def check_ballbar(record) -> dict:
    """``record`` if it is one axis's backlash from a circular test (``circle``) this version
    can interpret, else one ``InputError``."""
    kind = "ballbar record"
    _head(record, kind, BALLBAR_KEYS)
    if _date(record.get("date"), "date", kind) is None:
        _fail(kind, "date is missing")
    for key in ("plane", "visit", "source"):
        _text(record.get(key), key, kind)
    for key in ("radius_mm", "feed_mm_min"):
        _number(record.get(key), key, kind, minimum=0)
    _number(record.get("backlash_um"), "backlash_um", kind)
    _number(record.get("backlash_u_um"), "backlash_u_um", kind, minimum=0)
    return record


PROBING_KEYS = {"kind", "format", "machine_id", "axis", "date", "visit", "test_id",
                "kinematics", "play_arcsec", "play_u_arcsec", "errors", "errors_u", "source"}


def check_probing(record) -> dict:
    """``record`` if it is one rotary axis's play [arcsec] and its six geometric errors [um,
    urad; null where the probing cannot separate them] from probed spheres (``kinematics``)
    this version can interpret, else one ``InputError``."""
    kind = "probing record"
    _head(record, kind, PROBING_KEYS)
    if not schema.is_rotary(record["axis"]):
        _fail(kind, f"axis {record['axis']} is not rotary")
    _date(record.get("date"), "date", kind)
    for key in ("visit", "test_id", "kinematics", "source"):
        _text(record.get(key), key, kind)
    _number(record.get("play_arcsec"), "play_arcsec", kind, optional=True)
    _number(record.get("play_u_arcsec"), "play_u_arcsec", kind, optional=True, minimum=0)
    for key in ("errors", "errors_u"):
        values = record.get(key)
        if not isinstance(values, dict) or len(values) != 6:
            _fail(kind, f"{key} must map the axis's six error names to numbers or null")
        for name, value in values.items():
            _number(value, f"{key}.{name}", kind, optional=True)
    return record


STIFFNESS_KEYS = {"kind", "format", "machine_id", "axis", "date", "visit", "centres", "map",
                  "source"}
STIFFNESS_CENTRE_KEYS = {"centre_mm", "plane", "loads_n", "stiffness_n_per_um",
                         "stiffness_u_n_per_um"}
STIFFNESS_MAP_KEYS = {"form", "decided", "ram_top_mm"}


def check_stiffness(record) -> dict:
    """``record`` if it is one linear axis's static stiffness at the centres of one visit's
    loaded circles [N/um] and the form of the machine's stiffness map (``stiffness``) this
    version can interpret, else one ``InputError``."""
    kind = "stiffness record"
    _head(record, kind, STIFFNESS_KEYS)
    if record["axis"] not in schema.LINEAR_AXES:
        _fail(kind, f"axis {record['axis']} is not linear")
    _date(record.get("date"), "date", kind)
    for key in ("visit", "source"):
        _text(record.get(key), key, kind)
    centres = record.get("centres")
    if not isinstance(centres, list) or not centres:
        _fail(kind, "centres must list the centres of the visit")
    for i, c in enumerate(centres):
        if not isinstance(c, dict) or set(c) != STIFFNESS_CENTRE_KEYS:
            _fail(kind, f"centres[{i}] must hold {', '.join(sorted(STIFFNESS_CENTRE_KEYS))}")
        _numbers(c["centre_mm"], f"centres[{i}].centre_mm", kind, 3)
        _numbers(c["loads_n"], f"centres[{i}].loads_n", kind, None)
        if not isinstance(c["plane"], str) or record["axis"] not in c["plane"]:
            _fail(kind, f"centres[{i}].plane is {c['plane']!r}, not a plane of axis "
                        f"{record['axis']}")
        _number(c["stiffness_n_per_um"], f"centres[{i}].stiffness_n_per_um", kind)
        _number(c["stiffness_u_n_per_um"], f"centres[{i}].stiffness_u_n_per_um", kind,
                optional=True, minimum=0)
    found = record.get("map")
    if not isinstance(found, dict) or set(found) != STIFFNESS_MAP_KEYS:
        _fail(kind, f"map must hold {', '.join(sorted(STIFFNESS_MAP_KEYS))}")
    _text(found["form"], "map.form", kind)
    if not isinstance(found["decided"], bool):
        _fail(kind, f"map.decided is {found['decided']!r}, not true or false")
    _number(found["ram_top_mm"], "map.ram_top_mm", kind, optional=True)
    return record


CHECKS = {"forecast": check_forecast, "compensation": check_compensation,
          "trace": check_trace, "ballbar": check_ballbar, "probing": check_probing,
          "stiffness": check_stiffness}


def rows_of(kind: str, records: list[dict], recorded_at: str | None = None) -> list[tuple]:
    """Table rows of checked records, all stamped ``recorded_at`` (default now, UTC)."""
    stamp = recorded_at or now()
    return [(r["machine_id"], r["axis"], digest(r), stamp, canonical(CHECKS[kind](r)))
            for r in records]


def parse(kind: str, row: tuple, location: str) -> dict:
    """A stored row back as its record (plus ``recorded_at``), checked as when it was made
    and against its digest; one line naming the store and the row otherwise."""
    machine, axis, sha, recorded_at, text = row
    where = f"{kind} record {sha[:12]} of machine {machine} axis {axis}"
    try:
        record = json.loads(text)
        CHECKS[kind](record)
    except ValueError as err:
        raise InputError(f"{where} cannot be read: {err}", file=location) from None
    except InputError as err:
        raise InputError(f"{where} cannot be read: {err.message}", file=location) from None
    if digest(record) != sha or (record["machine_id"], record["axis"]) != (machine, axis):
        raise InputError(f"{where} does not match its digest: the table was changed outside "
                         "backlash", file=location)
    return {**record, "recorded_at": recorded_at}


# --------------------------------------------------------------------------- summaries
def summary(record: dict) -> dict:
    """A record as ``backlash fleet --json`` shows it (``last_forecast``,
    ``last_compensation``; docs/fleet.md lists the keys).

    A forecast: the mean over its points of the predicted backlash and of its 95 % bounds
    [um], the visit, day and operating hours [h] it is for, the model. A compensation: the
    controller, the reversal compensation and the largest correction of its table
    (correction = -error, either direction) [um].
    """
    import numpy as np

    head = {"date": record["recorded_at"][:10], "recorded_at": record["recorded_at"]}
    if record["kind"] == "compensation":
        table = record["table"]
        errors = np.r_[table["error_up_um"], table["error_down_um"]]
        return {**head, "controller": record["controller"], "source": record["source"],
                "reversal_compensation_um": _rounded(record["reversal_compensation_um"]),
                "max_abs_correction_um": _rounded(np.abs(errors).max()),
                "unit": record["unit"], "points": len(table["target"]), "files": record["files"]}
    points = record["points"]

    def mean(key):
        return _rounded(np.mean(points[key])) if key in points else None

    return {**head, "for_visit": record["visit"], "for_date": record["for_date"],
            "for_date_estimated": bool(record.get("for_date_estimated", False)),
            "for_operating_hours": _rounded(record["operating_hours"], 1),
            "backlash_um": mean("backlash_um"), "backlash_low_um": mean("backlash_low_um"),
            "backlash_high_um": mean("backlash_high_um"), "points": len(points["target"]),
            "model": record["model"], "model_dir": record["model_dir"]}


def _rounded(value, digits: int = 4):
    return None if value is None else round(float(value), digits)


# --------------------------------------------------------------------------- the API
def open_for_records(store):
    """An open store for recording: a ``Store`` as it is, else the store at a location
    (which must exist: records belong to the tests of an existing store)."""
    from pipeline.store import open_store
    from pipeline.store.base import Store

    opened = store if isinstance(store, Store) else open_store(store, write=True,
                                                                 parameter="store")
    if not opened.exists():
        raise InputError("holds no store yet; records belong to a store made by backlash "
                         "ingest", file=opened.location, parameter="store")
    return opened


def record(store, kind: str, records: list[dict], recorded_at: str | None = None
           ) -> Recorded | None:
    """Record ``records`` of ``kind`` (``CHECKS`` names the kinds) in one transaction: all or
    none; those already stored with the same content are left as they are. ``store`` None:
    every record is checked and none recorded (None returned): the runner asks so before it
    writes a result, so that a result whose records would be refused writes nothing either.

    Raises
    ------
    InputError
        A record this version cannot interpret, a store that does not exist or cannot be
        written; nothing is recorded.
    """
    rows = rows_of(kind, records, recorded_at)  # every record checked before the store
    if store is None:
        return None
    opened = open_for_records(store)
    added = opened.put_records(kind, rows)
    return Recorded(kind, added, len({r[:3] for r in rows}) - added, opened.location)


def read_records(store, kind: str) -> dict[tuple[str, str], list[dict]]:
    """Every record of ``kind`` by (machine_id, axis), oldest first (by ``recorded_at``);
    empty for a store written before records existed."""
    from pipeline.store import open_store
    from pipeline.store.base import Store

    opened = store if isinstance(store, Store) else open_store(store)
    out: dict[tuple[str, str], list[dict]] = {}
    for row in opened.get_records(kind):
        out.setdefault((row[0], row[1]), []).append(parse(kind, row, opened.location))
    return {key: sorted(found, key=_order) for key, found in sorted(out.items())}


def _order(record: dict) -> tuple:
    """Oldest first: by time of recording; records of one recording by the day (else visit)
    a forecast is for, or by controller."""
    return (record["recorded_at"], record.get("for_date") or record.get("date") or "",
            record.get("visit") or "",
            record.get("controller") or "", canonical(record))


def forecast_records(predictions, *, model: str, source: str, model_dir: str | None = None,
                     model_sha256: str | None = None, wear_rates: dict | None = None
                     ) -> list[dict]:
    """One forecast record per machine axis (and visit, when the points name one) of a
    predictions frame (``pipeline.workflows.predict.PredictionResult.predictions``).

    Parameters
    ----------
    predictions : DataFrame
        ``machine_id``, ``axis``, ``target`` [mm or deg], ``backlash_um`` and, where known,
        ``backlash_low_um``/``backlash_high_um`` [um], ``visit``, ``operating_hours`` [h] and
        ``started_at`` (the day the forecast is for).
    model, model_dir, model_sha256 : str
        The predictor's registry name, its directory and the SHA-256 of its ``model.json``.
    source : str
        Where the points came from, for errors.
    wear_rates : dict, optional
        (machine_id, axis) -> the model's wear-rate map (``position_mm``, ``rate``, ``low``,
        ``high`` [um per 1000 h]); key None for a map that holds for any axis.
    """
    missing = [c for c in ("machine_id", "axis") if c not in predictions]
    if missing:
        raise InputError("a forecast is recorded per machine axis: the points need machine_id "
                         "and axis", file=source, column=missing[0])
    keys = ["machine_id", "axis"] + (["visit"] if "visit" in predictions else [])
    wear_rates = wear_rates or {}
    records = []
    for key, part in predictions.groupby(keys, sort=True, dropna=False):
        machine, axis = str(key[0]), str(key[1])
        points = {c: _plain(part[c].to_numpy(float)) for c in POINT_KEYS if c in part}
        hours = part["operating_hours"].mean() if "operating_hours" in part else None
        records.append({
            "kind": "forecast", "format": RECORD_FORMAT, "machine_id": machine, "axis": axis,
            "visit": None if len(key) < 3 or _missing(key[2]) else str(key[2]),
            "for_date": _day(part["started_at"].min()) if "started_at" in part else None,
            "operating_hours": _plain(hours), "model": model, "model_dir": model_dir,
            "model_sha256": model_sha256, "points": points,
            "wear_rate": wear_rates.get((machine, axis), wear_rates.get(None))})
    return records


def _missing(value) -> bool:
    import pandas as pd

    return value is None or bool(pd.isna(value))


def _day(stamp) -> str | None:
    """The UTC day of a time (naive: taken as UTC), None when unknown."""
    import pandas as pd

    if _missing(stamp):
        return None
    stamp = pd.Timestamp(stamp)
    return (stamp.tz_convert("UTC") if stamp.tzinfo else stamp).date().isoformat()


def compensation_records(result) -> list[dict]:
    """One record per machine axis and controller of a compensate workflow's result
    (``pipeline.workflows.compensate.CompensationResult``): the per-target error of each
    approach direction [um] (the correction is its negative), the reversal compensation [um],
    the files written (paths under the output folder once written)."""
    profiles = {(p.machine_id, p.axis): p for p in getattr(result, "profiles", [])}
    written = getattr(result, "written", None)
    if not profiles or not written:
        raise InputError("holds no compensation; expected the result of compensate",
                         parameter="result")
    records = []
    for w in written:
        p = profiles.get((w.get("machine_id"), w.get("axis")))
        if p is None:
            raise InputError(f"names machine {w.get('machine_id')} axis {w.get('axis')} "
                             "without a profile; expected the result of compensate",
                             parameter="result")
        files = [str(result.path(name)) for name in w.get("files", {}).values()]
        backlash = w.get("backlash", p.backlash)
        records.append({
            "kind": "compensation", "format": RECORD_FORMAT, "machine_id": str(p.machine_id),
            "axis": str(p.axis), "controller": w.get("controller"), "source": p.source,
            "unit": schema.deviation_unit(str(p.axis)),
            "reversal_compensation_um": _plain(backlash),
            "interpolation_error_um": _plain(w.get("interpolation_error_um")),
            "table": {"target": _plain(p.target), "error_up_um": _plain(p.mean_up),
                      "error_down_um": _plain(p.mean_down)},
            "files": files})
    return records


def record_compensation(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record what a compensate workflow's result writes, per machine axis and controller.

    Parameters
    ----------
    store : str, path-like, Store or None
        An existing fleet store (folder or ``postgresql://`` URL); None: check the records
        only (``record``).
    result : CompensationResult
        What ``pipeline.workflows.compensate.compensate`` returned (written or not: the
        files are named as ``result.path`` names them).
    recorded_at : str, optional
        ISO time of recording (UTC); default now.

    Returns
    -------
    Recorded or None
        ``added`` new records; recording the same compensation again adds none.
    """
    return record(store, "compensation", compensation_records(result), recorded_at)


def record_forecast(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record a predict workflow's forecast (``pipeline.workflows.predict.PredictionResult``),
    one record per machine axis and visit (``forecast_records``): its ``points`` (the
    predictions with the day and operating hours each is for), the model by its registry
    name, the directory it was loaded from and the SHA-256 of its ``model.json``, and a wear
    map's wear-rate map per machine axis (``model_wear_rates``)."""
    import os

    points, trained = getattr(result, "points", None), getattr(result, "trained", None)
    if points is None or trained is None:
        raise InputError("holds no forecast; expected the result of predict",
                         parameter="result")
    model_dir, sha = getattr(result, "model_dir", None), None
    if model_dir is not None:
        from pathlib import Path

        from models.serving.persistence import digest as file_digest
        from models.serving.registry import MODEL_FILE

        model_dir, sha = os.fspath(model_dir), file_digest(Path(model_dir) / MODEL_FILE)
    records = forecast_records(points, model=trained.name, source=result.points_source,
                               model_dir=model_dir, model_sha256=sha,
                               wear_rates=model_wear_rates(trained))
    return record(store, "forecast", records, recorded_at)


def model_wear_rates(trained) -> dict | None:
    """The wear-rate map w(x) [um per 1000 h] of a wear-map model by (machine_id, axis) (key
    None: a single map for any axis), or None for a model without one."""
    import numpy as np

    estimator = trained.estimator
    if not hasattr(estimator, "wear_rate_map") or not getattr(estimator, "use_hours_", True):
        return None
    frame = estimator.wear_rate_map()
    groups = (frame.groupby(["machine_id", "axis"], sort=True) if "machine_id" in frame
              else [(None, frame)])

    def plain(values):
        return [float(v) if np.isfinite(v) else None for v in np.asarray(values, float)]

    return {None if key is None else tuple(map(str, key)): {
        "position_mm": plain(g["position_mm"]), "rate": plain(g["wear_rate_um_per_1000h"]),
        "low": plain(g["wear_rate_low"]), "high": plain(g["wear_rate_high"])}
        for key, g in groups}


def _plain(value):
    """Numbers and arrays as JSON values (numpy scalars to floats; NaN to None)."""
    import numpy as np

    if value is None:
        return None
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in np.asarray(value, dtype=float).tolist()]
    value = float(value)
    return value if math.isfinite(value) else None


# --------------------------------------------------------------------------- evidence
def trace_records(daily, source: str) -> list[dict]:
    """One trace record per machine axis and day of a monitor's ``daily`` frame
    (``pipeline.workflows.monitor.MonitorResult.daily``) with a lost motion [um, arcsec on a
    rotary axis] and its standard uncertainty; days without one are not recorded."""
    known = daily.dropna(subset=["lost_motion_um", "lost_motion_u_um"])
    return [{"kind": "trace", "format": RECORD_FORMAT, "machine_id": str(r.machine_id),
             "axis": str(r.axis), "date": str(r.date), "lost_motion_um": _plain(r.lost_motion_um),
             "lost_motion_u_um": _plain(r.lost_motion_u_um), "reversals": int(r.reversals),
             "source": source} for r in known.itertuples()]


def ballbar_records(items, dates: dict, source: str) -> list[dict]:
    """Two ballbar records per diagnosed circle (``pipeline.workflows.circle.CircleFigures``),
    one per axis of its plane: the play fitted to the axis [um] and its standard uncertainty,
    dated by ``dates`` (the circle's (machine, plane, visit, radius, feed) -> ISO day)."""
    out = []
    for item in items:
        c, d = item.circle, item.diagnosis
        if d is None:  # one direction only: no backlash
            continue
        day = dates[(c.machine_id, c.plane, c.visit, c.radius_mm, c.feed_mm_min)]
        for axis, term in zip(c.axes, ("backlash_1", "backlash_2")):
            out.append({"kind": "ballbar", "format": RECORD_FORMAT, "machine_id": c.machine_id,
                        "axis": axis, "date": day, "plane": c.plane, "visit": c.visit,
                        "radius_mm": float(c.radius_mm), "feed_mm_min": float(c.feed_mm_min),
                        "backlash_um": _plain(d.value[term]),
                        "backlash_u_um": _plain(d.u[term]), "source": source})
    return out


def record_trace(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record a monitor result's daily lost motion (``trace_records`` of its ``daily``), one
    trace record per machine axis and day with a value; the same days again add nothing."""
    daily = getattr(result, "daily", None)
    if daily is None:
        raise InputError("holds no daily lost motion; expected the result of monitor",
                         parameter="result")
    return record(store, "trace", trace_records(daily, result.source), recorded_at)


def record_ballbar(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record a circle result's backlash per axis (``ballbar_records`` of its ``circles``,
    dated by its ``dates``: the earliest ``started_at`` of each circle's runs); refused when
    the circular-test table did not date every run."""
    circles = getattr(result, "circles", None)
    if circles is None:
        raise InputError("holds no circle; expected the result of circle", parameter="result")
    if result.dates is None:
        raise InputError("a circle recorded in a fleet store needs its date: started_at on "
                         "every row", file=result.source, column="started_at")
    return record(store, "ballbar", ballbar_records(circles, result.dates, result.source),
                  recorded_at)


def probing_records(result) -> list[dict]:
    """One probing record per rotary axis of every machine and visit of a kinematics result
    (``pipeline.workflows.kinematics.KinematicsResult``): its play [arcsec] and its six
    errors [um, urad] with standard uncertainties, null where inseparable, dated by the
    earliest ``started_at`` of the visit (null when the table has none)."""
    from features.probing import axes_of

    out = []
    for m in getattr(result, "machines", None) or []:
        j = m.to_dict()
        for axis in axes_of(m.kinematics):
            own = [n for n in j["errors"] if n.split("_")[2] == axis]
            out.append({"kind": "probing", "format": RECORD_FORMAT, "machine_id": m.machine_id,
                        "axis": axis, "date": m.date, "visit": m.visit, "test_id": m.test_id,
                        "kinematics": m.kinematics, "play_arcsec": j["play_arcsec"][axis],
                        "play_u_arcsec": j["play_u_arcsec"][axis],
                        "errors": {n: j["errors"][n] for n in own},
                        "errors_u": {n: j["errors_u"][n] for n in own},
                        "source": getattr(result, "source", "") or "probing"})
    if not out:
        raise InputError("holds no machine; expected the result of kinematics",
                         parameter="result")
    return out


def record_probing(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record a kinematics result's probing records (``probing_records``) in ``store``."""
    return record(store, "probing", probing_records(result), recorded_at)


def stiffness_records(result) -> list[dict]:
    """One stiffness record per machine, visit and linear axis of a stiffness result
    (``pipeline.workflows.stiffness.StiffnessResult``): per centre of that visit whose plane
    holds the axis its stiffness [N/um] with its standard uncertainty, centre [mm], plane and
    loads [N]; the form of the machine's map; dated by the earliest ``started_at`` of the
    visit's runs (null when the table has none)."""
    out = []
    dates = getattr(result, "dates", None) or {}
    for m in getattr(result, "machines", None) or []:
        found = m["map"]
        shape = {"form": found["form"], "decided": bool(found["decided"]),
                 "ram_top_mm": _plain(found.get("ram_top_mm"))}
        for visit in dict.fromkeys(c["visit"] for c in m["centres"]):
            mine = [c for c in m["centres"] if c["visit"] == visit]
            for axis in (a for a in schema.LINEAR_AXES if any(a in c["plane"] for c in mine)):
                out.append({
                    "kind": "stiffness", "format": RECORD_FORMAT, "machine_id": m["machine_id"],
                    "axis": axis, "date": dates.get((m["machine_id"], visit)), "visit": visit,
                    "centres": [{"centre_mm": _plain(c["centre_mm"]), "plane": c["plane"],
                                 "loads_n": _plain(c["loads_n"]),
                                 "stiffness_n_per_um": _plain(c["stiffness_n_per_um"][axis]),
                                 "stiffness_u_n_per_um": _plain(
                                     c["stiffness_u_n_per_um"][axis])}
                                for c in mine if axis in c["plane"]],
                    "map": shape, "source": getattr(result, "source", "") or "stiffness"})
    if not out:
        raise InputError("holds no machine; expected the result of stiffness",
                         parameter="result")
    return out


def record_stiffness(store, result, recorded_at: str | None = None) -> Recorded | None:
    """Record a stiffness result's stiffness records (``stiffness_records``) in ``store``."""
    return record(store, "stiffness", stiffness_records(result), recorded_at)
