"""Find where simulation and measurement disagree, name the missing physical effect, add it
and show the gap shrink (``models.discovery``).

>>> import backlash as bl
>>> result = bl.discover("readings.csv")        # doctest: +SKIP
>>> result.named, result.rmse_after_um          # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import note
from pipeline.results import Result, TrackingRecord
from pipeline.steps.parameters import FORMAT, READINGS, SEED, Param
from pipeline.steps.source import readings_of, source_of

DEFAULT_BASELINE = "backlash,lead_error_linear"


# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{ess}", "--out", "{side}/d"],
    {"data": "{ess}", "out": "{side}/d"},
)

PARAMETERS = {
    "data": Param(READINGS, flag="DATA", reads_readings=True),  # as readings(), described here
    "format": FORMAT,
    "baseline": Param((str, list, tuple)),
    "out": Param((str, os.PathLike, None), "output folder for the report", required=True,
                 output="folder"),
    "seed": Param(SEED),
}


@dataclass
class DiscoveryResult(Result):
    """The effects named, step by step, and what is left of the gap.

    Attributes
    ----------
    discovery : models.discovery.Discovery
        Steps (effect, parameters, 95 % interval, delta BIC, CV gain, gap before and after
        [um]), ambiguous groups, residuals before and after, the unexplained gap, the
        measuring-system decision and its test.
    baseline : list of str
        Effects of the simulation model the search started from.
    source : str
        Where the readings came from.
    readings : DataFrame
        The validated readings (the report plots the residuals along their targets).
    """

    discovery: object
    baseline: list
    source: str
    readings: object = field(repr=False)
    seed: int = 0

    @property
    def named(self) -> list[str]:
        """Effects named, in the order they were added."""
        return self.discovery.named

    @property
    def ambiguous(self) -> list[list[str]]:
        """Groups of effects that explain the gap equally well on this design."""
        return self.discovery.ambiguous

    @property
    def steps(self) -> list:
        return self.discovery.steps

    @property
    def rmse_before_um(self) -> float:
        """Gap [um]: RMSE of the baseline simulation against the measurement."""
        return self.discovery.rmse_before_um

    @property
    def rmse_after_um(self) -> float:
        """Gap [um] with the named effects added."""
        return self.discovery.rmse_after_um

    @property
    def repeatability_um(self) -> float:
        return self.discovery.repeatability_um

    @property
    def measuring_system(self) -> dict | None:
        """The measuring system decided from the interior reversal values, with its test
        (statistic, p), or None when the readings hold none."""
        return self.discovery.measuring_system

    @property
    def unexplained(self) -> dict | None:
        """The structure left in the residual, or None when the gap is explained."""
        return self.discovery.unexplained

    def write(self, out) -> dict[str, Path]:
        """``discovery.html`` and ``discovery.png`` (``pipeline.reports.discovery_report``)."""
        from pipeline.reports import discovery_report

        self.files = discovery_report.write(self.discovery, self.readings, out, self.source)
        return self.files

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan(self.discovery.to_dict())

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``discover``: baseline, effects named, the gap, the report."""
        from pipeline.results import data_hash

        d = self.discovery
        return TrackingRecord(
            "discover", f"discover {self.source}",
            params={"data": self.source, "baseline": ",".join(self.baseline),
                    "data_sha256": data_hash(self.readings),
                    "named": ",".join(d.named) or "none",
                    "measuring_system": (d.measuring_system or {}).get("system") or "n/a"},
            metrics={"rmse_before_um": d.rmse_before_um, "rmse_after_um": d.rmse_after_um,
                     "repeatability_um": d.repeatability_um},
            artifacts=list(self.files.values()), artifact_path="discover")


def discover(data, *, format: str = "auto", baseline=DEFAULT_BASELINE,
             seed: int = 0) -> DiscoveryResult:
    """Name the physical effects the baseline simulation model is missing.

    Parameters
    ----------
    data : str, path or DataFrame
        Readings (the columns of docs/data-contract.md; ``measured_at`` for time effects): a
        file or a fleet store (a folder or a ``postgresql://`` URL made by
        ``backlash ingest``).
    format : str, default 'auto'
        Input layout of a file.
    baseline : str or list of str, default 'backlash,lead_error_linear'
        Effects of the simulation model: names of ``models.physics.effects.EFFECTS``,
        comma-separated.
    seed : int, default 0
        Seed of the bootstrap that checks each named effect is stable.

    Returns
    -------
    DiscoveryResult
    """
    from models import discovery as search

    names = search.check_baseline(baseline)  # before the data are read
    readings = readings_of(data, format)
    source = source_of(data, readings)
    found = search.discover(readings, names, random_state=seed, source=source)
    for text in found.notes:
        note(text)
    return DiscoveryResult(found, names, source, readings, seed, notes=list(found.notes))
