"""The printable test report: one page per ISO positioning test, as HTML and PDF.

>>> import backlash as bl
>>> result = bl.report(["ess_mcu1025_ISO230.dat", "psi_sls_stepper_ISO230.dat"])  # doctest: +SKIP
>>> result.write("report/")         # iso_report.html, iso_report.pdf              # doctest: +SKIP

The figures are ``iso``'s (the same standard, outlier rule and uncertainty budget); the
pages are drawn by ``pipeline.reports.iso_report``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from features import standards
from pipeline.results import Result
from pipeline.steps import iso as iso_workflow
from pipeline.workflows import Constraints, Workflow, check_params

PARAMETERS = Constraints(iso_workflow._parameters)


@dataclass
class ReportResult(Result):
    """The tests of a report and the figures it prints.

    Attributes
    ----------
    iso : pipeline.workflows.iso.IsoResult
        Figures, readings, outliers, standard and budget of every test (one page each).
    """

    iso: object

    def write(self, out) -> dict[str, Path]:
        """Write ``iso_report.pdf`` and ``iso_report.html`` into the folder ``out``."""
        from pipeline.reports.iso_report import write_report

        self.files = write_report(self.iso, out)
        return self.files

    def to_json(self) -> list[dict]:
        """The figures of every test, as ``iso --json`` prints them."""
        return self.iso.to_json()


def report(data, format: str = "auto", drop_outliers: bool = False, uncertainty=None,
           standard: str = standards.DEFAULT) -> ReportResult:
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
        An ISO/TR 230-9 budget: every axis figure printed as ``value ± U`` (``iso``).
    standard : str
        The standard whose figures the pages print (``features.standards``).

    Returns
    -------
    ReportResult
        Write it with ``write(out)``; nothing is written before.

    Raises
    ------
    InputError
        As ``iso``: unreadable readings or budget, a standard that is not supported.
    """
    params = {"data": data, "format": format, "drop_outliers": drop_outliers,
              "uncertainty": uncertainty, "standard": standard}
    check_params(PARAMETERS, params, "report")
    result = iso_workflow.iso(**params)
    return ReportResult(iso=result, notes=list(result.notes))


WORKFLOW = Workflow(
    name="report", function=report,
    summary="Printable test report (HTML and PDF): conditions, per-target table, axis figures "
            "and chart of every test, one page each.",
    inputs=("data", "uncertainty"))
