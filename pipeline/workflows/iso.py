"""The ``iso`` job: ISO 230-2 figures of every test in one or more readings files, per target
and per axis, with the readings far from their siblings flagged (and, on request, left out).
The analysis is ``pipeline.steps.iso``, which the ``report`` job shares.

>>> import backlash as bl
>>> result = bl.iso("ess_mcu1025_ISO230.dat")             # doctest: +SKIP
>>> result.figures[["test_id", "A", "E", "M", "R", "B"]]  # doctest: +SKIP
>>> result.plot("ess.png")                                # doctest: +SKIP

With an ISO/TR 230-9 budget (``features.uncertainty``) each test also gets the expanded
uncertainties of A, E, M, R and B at its own measuring length and number of runs:

>>> result = bl.iso("ess_mcu1025_ISO230.dat", uncertainty="paper_uncertainty.toml")  # doctest: +SKIP
>>> result.figures[["B", "U_B_um"]]                                                 # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from features import standards
from features.readings.errors import InputError
from pipeline.steps.constraints import StrOptions
from pipeline.steps.iso import IsoFigures
from pipeline.steps.parameters import BUDGET, FORMAT, RAW_LOG, READINGS, Param, readings

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--machine", "M01", "--axis", "Y"],
    {"data": "{two}", "machine": "M01", "axis": "Y"},
)

# the iso job's table; report's data and standard are the same parameters
PARAMETERS = {
    "data": readings(flag="FILE", accepts=(*READINGS, list, tuple), nargs="+"),
    "format": FORMAT,
    "drop_outliers": Param(("boolean",)),
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
    # its own help: every standard of the records, those not supported marked (refused)
    "standard": Param((StrOptions(standards.NAMES),), standards.help_text()),
    **RAW_LOG,  # a raw log's reader's (the runner reads the log with them)
}


@dataclass
class IsoResult(IsoFigures):
    """ISO 230-2 figures of every test (``pipeline.steps.iso.IsoFigures``: ``targets``,
    ``figures``, ``outliers``, ``dropped``, ``budget``, ``standard``, ``readings``,
    ``sources``), with the job's files: the figures as CSV and the ISO chart."""

    def plot(self, path) -> Path:
        """Write the ISO chart (one panel per test, at most ``iso_chart.MAX_PANELS``) as PNG.

        Raises
        ------
        InputError
            ``path`` is not a .png name, or there are too many tests for one chart.
        """
        from pipeline.reports.iso_chart import MAX_PANELS, plot_tests

        path = Path(path)
        if path.suffix.lower() != ".png":
            raise InputError("expected a .png file name", file=path, parameter="path")
        if len(self.figures) > MAX_PANELS:
            raise InputError(f"the chart draws at most {MAX_PANELS} tests, the readings have "
                             f"{len(self.figures)}; split them first", parameter="path")
        plot_tests(self.targets, self.figures, path)
        self.files["chart"] = path
        return path

    def write(self, out) -> dict[str, Path]:
        """Write ``iso_figures.csv``, ``iso_targets.csv`` and (for at most ``MAX_PANELS``
        tests) the chart ``iso_chart.png`` into the folder ``out``."""
        from features.readings.fileio import atomic_path
        from pipeline.reports.iso_chart import MAX_PANELS

        out = Path(out)
        for role, frame in (("figures", self.figures), ("targets", self.targets)):
            with atomic_path(out / f"iso_{role}.csv") as tmp:
                frame.to_csv(tmp, index=False)
            self.files[role] = out / f"iso_{role}.csv"
        if len(self.figures) <= MAX_PANELS:
            self.plot(out / "iso_chart.png")
        return self.files


def iso(data, format: str = "auto", drop_outliers: bool = False,
        uncertainty=None, standard: str = standards.DEFAULT) -> IsoResult:
    """ISO 230-2 figures of every test (ISO 230-2:2014 clause 2; ``features.iso230``).

    Parameters
    ----------
    data : str, path-like, DataFrame or list of them
        One or more readings files (``pipeline.steps.iso.read_tests``), or frames ``read``
        returned.
    format : str
        Input layout of a file, ``"auto"`` to recognise it.
    drop_outliers : bool
        Leave the readings flagged as outliers out of the figures (default: flag, keep).
    uncertainty : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget, a TOML file (e.g. ``experiments/data/paper_uncertainty.toml``):
        adds the expanded uncertainties ``U_A_um, U_E_um, U_M_um, U_R_um, U_B_um`` of every
        test, at its own measuring length and runs per direction
        (``features.uncertainty.with_uncertainty``). Linear axes only.
    standard : str
        The standard whose figures to compute, a name of ``features.standards.STANDARDS``;
        only the supported ones are accepted (``"iso230-2"``).

    Returns
    -------
    IsoResult
        Figures per target and per test; each outlier is a note.

    Raises
    ------
    InputError
        Unreadable readings or budget, a non-physical budget, a budget for a rotary axis, a
        standard that is not supported (the error gives the reason).
    """
    record = standards.standard(standard)
    from features import uncertainty as unc

    budget = None if uncertainty is None else unc.checked_budget(uncertainty)
    return IsoResult.of(data, format, drop_outliers, budget, record)
