"""Result objects: what a workflow returns to the CLI, an experiment or a Python user.

A result holds frames, figures and notes; it knows which files it writes (``write``), what it
logs to MLflow (``tracking_record``, logged by the one adapter ``pipeline.tracking.runs.log_result``)
and its machine-readable form (``to_dict``; ``to_json`` its text). It never prints: the CLI decides what to show.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

# Exit code of a run whose result carries alerts (drift, fleet): a result, not a failure.
ALERT_EXIT = 3


@dataclass
class TrackingRecord:
    """What one result logs to MLflow: the run's experiment and name, params, metrics,
    artifacts (files written by ``write``, logged under ``artifact_path``) and tags."""

    experiment: str
    run_name: str
    params: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    artifacts: list[Path] = field(default_factory=list)
    artifact_path: str | None = None
    tags: dict = field(default_factory=dict)


@dataclass
class RunRecord(TrackingRecord):
    """A ``TrackingRecord`` with what model runs add.

    Attributes
    ----------
    model : dict or None
        A trained model to log and register as ``backlash-predictor``
        (``models.serving.description.describe``).
    children : list of TrackingRecord
        Runs nested under this one (one per compared model, one per tuning trial).
    promote : bool
        Give the champion alias to the best registered model of this record and its children
        (``standing``: highest backtest skill against persistence, else lowest
        ``test_rmse_um``) when it beats the champion on the same data (``data_sha256``).
    status : str
        How the run ends: ``FINISHED``, or ``FAILED`` for a trial that failed.
    """

    model: dict | None = None
    children: list = field(default_factory=list)
    promote: bool = False
    status: str = "FINISHED"


def data_hash(frame) -> str:
    """Content hash of a data frame, logged with runs (``data_sha256``).

    The sha256 of the column names, their dtypes and pandas' 64-bit hash of every row's values
    (``pandas.util.hash_pandas_object``, index left out): equal content gives the same hash,
    a changed value, column name or dtype another. Hashing the values in place is an order of
    magnitude faster than writing the frame out as text.
    """
    import hashlib

    import pandas as pd

    digest = hashlib.sha256()
    for name, dtype in frame.dtypes.items():
        digest.update(f"{name!s}\x1f{dtype!s}\x1e".encode())
    rows = pd.util.hash_pandas_object(frame, index=False).to_numpy(dtype="<u8")
    digest.update(rows.tobytes())
    return digest.hexdigest()


@dataclass
class Result:
    """Base of every workflow result.

    Attributes
    ----------
    notes : list of str
        What a user should know about this result (data left out, choices made, limits of
        the evidence). The CLI prints them as ``note: ...``; a Python user reads them here.
    files : dict of str to Path
        Files written by ``write``, by role (empty until then).
    """

    notes: list[str] = field(default_factory=list, kw_only=True)
    files: dict[str, Path] = field(default_factory=dict, kw_only=True)

    def __init_subclass__(cls, **kwargs):
        # every subclass keeps the short repr: @dataclass adds its own __repr__ only to a class
        # that does not define one
        super().__init_subclass__(**kwargs)
        if "__repr__" not in cls.__dict__:
            cls.__repr__ = Result.__repr__

    def __repr__(self) -> str:
        """``Name(data='file.dat', key=value, ..., notes=N)``: the data's name, then every
        field in brief (frames as their shape ``rows x columns``, collections as their length,
        numbers to 4 digits), cut at ``REPR_CHARS`` characters."""
        items = {"data": repr(data_name(self))} if data_name(self) else {}
        items.update(self.repr_items())
        items["notes"] = str(len(self.notes))
        if self.files:
            items["files"] = str(len(self.files))
        text = ", ".join(f"{k}={v}" for k, v in items.items())
        if len(text) > REPR_CHARS:
            text = text[:REPR_CHARS - 3].rsplit(", ", 1)[0] + ", ..."
        return f"{type(self).__name__}({text})"

    def repr_items(self) -> dict[str, str]:
        """The key figures ``repr`` shows, by name, as text: every field shown by the
        dataclass's repr in brief (``brief``), except the data's name, notes and files. A
        result may override it to put its own figures first."""
        from dataclasses import fields

        skip = {"notes", "files", "source", "sources"}
        out = {}
        for f in fields(self):
            text = brief(getattr(self, f.name)) if f.repr and f.name not in skip else None
            if text is not None:
                out[f.name] = text
        return out

    def write(self, out: str | Path) -> dict[str, Path]:
        """Write the result's files under ``out`` (atomically) and return them by role."""
        return self.files

    def to_dict(self) -> dict | list:
        """The machine-readable form as Python objects (what ``to_json`` writes)."""
        raise NotImplementedError(f"{type(self).__name__} has no JSON form")

    def to_json(self) -> str:
        """The JSON text the CLI prints with ``--json`` (NaN as null)."""
        from features.readings.fileio import clean_nan, dumps

        return dumps(clean_nan(self.to_dict()))

    def tracking_record(self) -> TrackingRecord | None:
        """What to log to MLflow, or None for a result that is not tracked."""
        return None


REPR_CHARS = 300  # the longest repr of a result, in characters


def data_name(result) -> str | None:
    """The file name of the data a result was made from (``source``, ``sources``, the
    readings' ``source``, ``parameters['data']``), ``N files`` for several, or None."""
    found = getattr(result, "source", None)
    if not found:
        sources = getattr(result, "sources", None) or {}
        names = sorted({str(v) for v in sources.values()}) if isinstance(sources, dict) else []
        found = names[0] if len(names) == 1 else (f"{len(names)} files" if names else None)
    if not found:
        readings = getattr(result, "readings", None)
        found = getattr(readings, "attrs", {}).get("source")
    if not found:
        parameters = getattr(result, "parameters", None)
        found = parameters.get("data") if isinstance(parameters, dict) else None
    return Path(str(found)).name if found else None


def brief(value) -> str | None:
    """``value`` in a few characters for a repr, or None to leave it out: a frame or array
    as its shape (``12x8``), a number to 4 significant digits, text quoted and cut at 40
    characters, a collection as its length in brackets (``[4]``), a nested result or any
    other object as its ``name`` or class name; None and empty collections are left out."""
    if value is None:
        return None
    shape = getattr(value, "shape", None)
    if isinstance(shape, tuple):
        return "x".join(str(n) for n in shape)
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, (int, float)):
        return f"{value:.4g}"
    if isinstance(value, (str, Path)):
        text = value.name if isinstance(value, Path) else value
        return repr(text if len(text) <= 40 else text[:37] + "...")
    if isinstance(value, (list, tuple, set, dict)):
        return f"[{len(value)}]" if value else None
    name = getattr(value, "name", None)
    return repr(name) if isinstance(name, str) else type(value).__name__


def axis_alerts(items) -> list[dict]:
    """Every alert of every machine axis in ``items`` (each with ``machine_id``, ``axis`` and
    ``alerts``), as ``kind``, ``message``, ``machine_id``, ``axis``."""
    return [{**a, "machine_id": i.machine_id, "axis": i.axis} for i in items for a in i.alerts]
