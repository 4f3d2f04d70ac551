"""The backlash paper's results (best epoch, regression R, ANOVA Table 5, k-NN accuracy) on one
data set of paired tests, with and without the deviation inputs (``pipeline.replication``).

>>> import backlash as bl
>>> result = bl.replicate("twin/readings.csv", truth="twin/truth.csv")   # doctest: +SKIP
>>> print(result.markdown())                                             # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from numbers import Integral
from pathlib import Path

from features.readings.errors import Progress
from pipeline.results import Result
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import FORMAT, RANDOM_SEED, READINGS, TRUTH, Param
from pipeline.steps.source import readings_of, source_of

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--boot", "5", "--out", "{side}/rep"],
    {"data": "{twin}", "boot": 5, "out": "{side}/rep"},
)

PARAMETERS = {
    "data": Param(READINGS, flag="DATA", reads_readings=True),  # as readings(), described here
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "output folder", required=True, output="folder"),
    "truth": replace(TRUTH, help=None),  # described by replicate's docstring
    "boot": Param((Interval(Integral, 0, None, closed="left"),)),
    "seed": RANDOM_SEED,
}


@dataclass
class ReplicationResult(Result):
    """Every replicated number, with and without the deviation inputs.

    Attributes
    ----------
    cases : dict
        ``"with deviations"`` and ``"without deviations"``: the network's run (best epoch,
        regression R per phase, training history), k-NN accuracy, ANOVA -ln(p) per input and
        its order, verdicts given the others (``pipeline.replication.replicate``).
    source : str
        Where the readings came from.
    """

    cases: dict
    source: str

    @property
    def rows(self) -> list[dict]:
        """The side-by-side table: quantity, paper, with deviations, without, note."""
        from pipeline.replication import comparison_rows

        return comparison_rows(self.cases)

    def markdown(self) -> str:
        """The side-by-side table as Markdown."""
        from pipeline.replication import markdown

        return markdown(self.rows)

    def to_dict(self) -> dict:
        """The side-by-side table (``rows``: quantity, paper, with and without deviations,
        note) and the source."""
        return {"source": self.source, "rows": self.rows}

    def write(self, out) -> dict[str, Path]:
        """``replication.html``, ``.md``, ``.json`` and the Fig. 10 and 13 figures."""
        from pipeline.replication import write_replication

        self.files = write_replication(self.cases, out, source=self.source)
        return self.files


def replicate(data, *, format: str = "auto", truth=None, boot: int = 100, seed: int = 0,
              progress: Progress | None = None) -> ReplicationResult:
    """Replicate the backlash paper's results on paired linear and pendulum tests.

    Parameters
    ----------
    data : str, path or DataFrame
        Readings with paired linear and pendulum tests: a file or a fleet store (a folder or a
        ``postgresql://`` URL made by ``backlash ingest``).
    format : str, default 'auto'
        Input layout of a file.
    truth : str, path or DataFrame, optional
        The twin's truth table (written by ``simulate``): also the k-NN accuracy the true backlash would
        reach in the measured classes (the ceiling set by noise).
    boot : int, default 100
        Bootstrap resamples.
    seed : int, default 0
        Random seed.
    progress : callable, optional
        ``progress(done, total, what)``, told as each case (with and without the deviation
        inputs) starts.

    Returns
    -------
    ReplicationResult
    """
    from features.table import PAPER_FEATURES, feature_table
    from pipeline import replication

    readings = readings_of(data, format)
    table = feature_table(readings, target="paper", features=list(PAPER_FEATURES))
    truth_um = None
    if truth is not None:
        from models.estimators.evaluation import read_truth, true_backlash

        frame = truth if not isinstance(truth, (str, os.PathLike)) else read_truth(truth)
        truth_um = true_backlash(table.meta, frame, table.target_kind)
    cases = replication.replicate(table.X, table.y, table.meta, seed, boot, truth_um,
                                  progress=progress)
    source = source_of(data, readings)
    return ReplicationResult(cases, source)
