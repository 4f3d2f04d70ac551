"""The printable test report: one page per ISO positioning test, as HTML and PDF.

>>> import backlash as bl
>>> result = bl.report(["ess_mcu1025_ISO230.dat", "psi_sls_stepper_ISO230.dat"])  # doctest: +SKIP
>>> result.write("report/")         # iso_report.html, iso_report.pdf              # doctest: +SKIP

The figures are ``iso``'s (the same standard, outlier rule and uncertainty budget); the
pages are drawn by ``pipeline.reports.iso_report``. A meta file (``pipeline.reports.report_meta``) names the
operator, the instrument and its calibration and the environment sensors on every page:

>>> result = bl.report("ess_mcu1025_ISO230.dat", uncertainty="paper_uncertainty.toml",
...                    meta="meta.toml")                                     # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from features import standards
from features import uncertainty as unc
from pipeline.reports.report_meta import ReportMeta, read_meta
from pipeline.results import Result
from pipeline.steps.constraints import StrOptions
from pipeline.steps.iso import IsoFigures
from pipeline.steps.parameters import BUDGET, FORMAT, RAW_LOG, READINGS, Param, readings

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--axis", "Y", "--out", "{side}/rep"],
    {"data": "{two}", "axis": "Y", "out": "{side}/rep"},
)

# iso's readings, outlier rule, budget and standard (the same parameters as the iso job's,
# pipeline.workflows.iso); the report's own output and meta file
PARAMETERS = {
    "data": readings(flag="FILE", accepts=(*READINGS, list, tuple), nargs="+"),
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "folder for iso_report.html and iso_report.pdf",
                 metavar="DIR", required=True, output="folder"),
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
    "drop_outliers": Param(("boolean",)),
    "meta": Param((str, os.PathLike, dict, ReportMeta, None), metavar="META.toml"),
    # its own help: every standard of the records, those not supported marked (refused)
    "standard": Param((StrOptions(standards.NAMES),), standards.help_text()),
    **RAW_LOG,  # a raw log's reader's (the runner reads the log with them)
}


@dataclass
class ReportResult(Result):
    """The tests of a report and the figures it prints.

    Attributes
    ----------
    iso : pipeline.steps.iso.IsoFigures
        Figures, readings, outliers, standard and budget of every test (one page each), as
        the ``iso`` job computes them.
    meta : pipeline.reports.report_meta.ReportMeta or None
        Operator, instrument and its calibration, sensors and remarks, printed on every page.
    """

    iso: object
    meta: ReportMeta | None = None

    def write(self, out) -> dict[str, Path]:
        """Write ``iso_report.pdf`` and ``iso_report.html`` into the folder ``out``."""
        from pipeline.reports.iso_report import write_report

        self.files = write_report(self.iso, out, self.meta)
        return self.files

    def to_dict(self) -> list[dict]:
        """The figures of every test, as ``iso --json`` prints them."""
        return self.iso.to_dict()


def report(data, format: str = "auto", drop_outliers: bool = False, uncertainty=None,
           standard: str = standards.DEFAULT, meta=None) -> ReportResult:
    """The test report of every test in one or more readings files.

    Parameters
    ----------
    data : str, path-like, DataFrame or list of them
        Readings files (any accepted layout) or frames ``read`` returned; any number of tests.
    format : str
        Input layout of the files, ``"auto"`` to recognise each.
    drop_outliers : bool
        Leave the flagged outliers out of the figures (they stay on the charts, ringed).
    uncertainty : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget of the tests' axis, a TOML file: every axis figure printed as
        ``value ± U`` (U as the ``iso`` job computes it), with the coverage factor k and the
        budget's name (its ``name`` key, else its file's name) and digest
        (``UncertaintyBudget.digest``).
    standard : str
        The standard whose figures the pages print (``features.standards``).
    meta : str, path-like, dict or ReportMeta, optional
        A meta file's ``[report]`` table (``pipeline.reports.report_meta``), printed on every
        page above the signature block: ``operator``, ``organisation``, ``instrument``, its
        serial and calibration date (``instrument_serial``, ``instrument_calibrated_on``),
        environment ``sensors``, ``remarks``.

    Returns
    -------
    ReportResult
        Write it with ``write(out)``; nothing is written before.

    Raises
    ------
    InputError
        As ``iso``: unreadable readings or budget, a budget of another axis than a test's, a
        standard that is not supported; an unreadable meta file (naming its key).
    """
    signed = None if meta is None else read_meta(meta)
    budget = None
    if uncertainty is not None:
        budget = unc.checked_budget(uncertainty)
        if not budget.name:  # the page names the budget: by its file when it has no name
            given = isinstance(uncertainty, (str, os.PathLike))
            budget = replace(budget, name=Path(uncertainty).name if given else "")
    result = IsoFigures.of(data, format, drop_outliers, budget, standards.standard(standard))
    notes = list(result.notes)
    if signed is not None:  # a calibration after the test refused, an expired one noted
        notes += signed.against_tests(result.readings)
    return ReportResult(iso=result, meta=signed, notes=notes)
