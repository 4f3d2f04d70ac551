"""Result objects: what a workflow returns to the CLI, an experiment or a Python user.

A result holds frames, figures and notes; it knows which files it writes (``write``), what it
logs to MLflow (``tracking_record``, logged by the one adapter ``pipeline.tracking.log_result``)
and its machine-readable form (``to_json``). It never prints: the CLI decides what to show.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


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

    def write(self, out: str | Path) -> dict[str, Path]:
        """Write the result's files under ``out`` (atomically) and return them by role."""
        return self.files

    def to_json(self) -> dict | list:
        """The machine-readable form the CLI prints with ``--json``."""
        raise NotImplementedError(f"{type(self).__name__} has no JSON form")

    def tracking_record(self) -> TrackingRecord | None:
        """What to log to MLflow, or None for a result that is not tracked."""
        return None


def axis_alerts(items) -> list[dict]:
    """Every alert of every machine axis in ``items`` (each with ``machine_id``, ``axis`` and
    ``alerts``), as ``kind``, ``message``, ``machine_id``, ``axis``."""
    return [{**a, "machine_id": i.machine_id, "axis": i.axis} for i in items for a in i.alerts]
