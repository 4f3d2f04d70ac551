"""ISO 230-2 figures of every test in one or more readings files: per target and per axis,
with the readings far from their siblings flagged (and, on request, left out). The ``iso``
and ``report`` jobs share it (``pipeline.workflows.iso`` is the job's record).

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

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from features import standards
from features.readings import schema
from features.readings.errors import InputError, note
from pipeline.results import Result
from pipeline.steps.parameters import BUDGET, FORMAT, RAW_LOG, READINGS, Param, readings
from pipeline.workflows import check_params, readings_of
from pipeline.workflows.constraints import StrOptions

if TYPE_CHECKING:  # a budget is read when one is given: the module stays light for --help
    from features.uncertainty import UncertaintyBudget

# Keys of each test's object in the JSON form (``backlash iso --json``): a public contract.
JSON_KEYS = ("machine_id", "axis", "visit", "test_id", "unit", "A", "A_up", "A_down", "E",
             "E_up", "E_down", "M", "R", "R_up", "R_down", "B", "B_mean")
PER_TARGET_KEYS = ("target", "mean_up", "mean_down", "s_up", "s_down", "B_i", "R_i")
# Columns of the figures table the CLI prints.
TABLE_COLUMNS = ("test_id", "unit", "A", "E", "M", "R", "B", "B_mean")
# Expanded uncertainties [um] added to the figures, the JSON objects and the table when a
# budget is given, by the figure of ``features.uncertainty.expanded_parameters_um`` they take.


# the iso job's table (pipeline.workflows.iso); report shares its data and standard
PARAMETERS = {
    "data": readings(flag="FILE", accepts=(*READINGS, list, tuple), nargs="+"),
    "format": FORMAT,
    "drop_outliers": Param(("boolean",), "leave flagged outlier readings out of the figures"),
    "uncertainty": Param(BUDGET, "ISO/TR 230-9 budget: add U_A_um ... U_B_um (expanded "
                         "uncertainties at each test's measuring length)", metavar="BUDGET.toml"),
    "standard": Param((StrOptions(standards.NAMES),), standards.help_text()),
    **RAW_LOG,  # a raw log's reader's (the runner reads the log with them)
}


@dataclass
class IsoResult(Result):
    """ISO 230-2 figures of every test (um, arcsec for rotary axes).

    Attributes
    ----------
    targets : DataFrame
        One row per test and target (``features.iso230.per_target``).
    figures : DataFrame
        One row per test: A, E, M, R, B and their directional parts
        (``features.iso230.axis_figures``); with a budget also
        ``features.uncertainty.TEST_UNCERTAINTY_KEYS``, the
        expanded uncertainties [um] of A, E, M, R and B.
    outliers : DataFrame
        The readings flagged as outliers (``features.iso230.outliers``), whether dropped or
        kept.
    dropped : bool
        Whether the outliers were left out of the figures.
    budget : features.uncertainty.UncertaintyBudget or None
        The uncertainty budget the ``U_*_um`` columns come from, if one was given.
    standard : features.standards.Standard
        The standard the figures follow.
    readings : DataFrame or None
        Every reading of the tests, the outliers included whether dropped or kept.
    sources : dict
        The file (or frame) each test was read from, by its ``TEST_KEYS`` tuple.
    """

    targets: object  # pandas.DataFrame
    figures: object
    outliers: object
    dropped: bool = False
    budget: UncertaintyBudget | None = None
    standard: standards.Standard = standards.ISO230_2
    readings: object = None
    sources: dict = field(default_factory=dict)

    def _extra(self) -> list[str]:
        """The uncertainty columns the figures carry (none without a budget)."""
        from features.uncertainty import TEST_UNCERTAINTY_KEYS

        return [k for k in TEST_UNCERTAINTY_KEYS if k in self.figures.columns]

    def repr_items(self) -> dict[str, str]:
        return {"tests": str(len(self.figures)), **super().repr_items()}

    def to_json(self) -> list[dict]:
        """One object per test with ``JSON_KEYS`` (and, with a budget,
        ``features.uncertainty.TEST_UNCERTAINTY_KEYS``)
        and its ``per_target`` rows (``PER_TARGET_KEYS``); NaN becomes None."""
        from features.readings.fileio import clean_nan

        keys = list(schema.TEST_KEYS)
        # one pass over all targets (a dict per row), grouped by test: per-test frame
        # lookups cost seconds on a fleet of thousands of tests
        targets = self.targets.sort_values([*keys, "target"], kind="stable")
        per_test: dict[tuple, list] = {}
        for test, row in zip(targets[keys].itertuples(index=False, name=None),
                             targets[list(PER_TARGET_KEYS)].to_dict("records")):
            per_test.setdefault(test, []).append(row)
        out = []
        for row in self.figures[list(JSON_KEYS) + self._extra()].to_dict("records"):
            row["per_target"] = per_test[tuple(row[k] for k in keys)]
            out.append(row)
        return clean_nan(out)

    def table(self) -> str:
        """The axis figures as a text table (three decimals), with the expanded uncertainties
        when a budget was given."""
        return self.figures[list(TABLE_COLUMNS) + self._extra()].to_string(
            index=False, float_format=lambda v: f"{v:.3f}")

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


def read_tests(data, format: str = "auto"):
    """The readings of one or more files (or frames) as one frame, and the source of each test.

    Parameters
    ----------
    data : str, path-like, DataFrame or list of them
        Readings files in any accepted layout, fleet stores, or frames ``read`` returned.
    format : str
        Input layout of the files, ``"auto"`` to recognise each.

    Returns
    -------
    readings : DataFrame
        Every reading, indexed 0..n-1.
    sources : dict
        ``TEST_KEYS`` tuple -> the file (or frame) the test came from.

    Raises
    ------
    InputError
        An unreadable input, an empty list, or a test (same ``TEST_KEYS``) in two inputs.
    """
    import pandas as pd

    items = list(data) if isinstance(data, (list, tuple)) else [data]
    if not items:
        raise InputError("is empty; expected one or more readings files", parameter="data")
    keys, frames, sources = list(schema.TEST_KEYS), [], {}
    for i, item in enumerate(items):
        if not isinstance(item, (str, os.PathLike, pd.DataFrame)):
            raise InputError(f"item {i} is a {type(item).__name__}; expected a readings file "
                             "or frame", parameter="data")
        frame = readings_of(item, format)
        name = frame.attrs.get("source", f"data[{i}]")
        for test in frame[keys].drop_duplicates().itertuples(index=False, name=None):
            if test in sources:  # two inputs, one test: which readings would be its?
                raise InputError(f"test {test[3]!r} (machine {test[0]}, axis {test[1]}, visit "
                                 f"{test[2]}) is also in {sources[test]}", file=name)
            sources[test] = name
        frames.append(frame)
    if len(frames) == 1:
        return frames[0], sources
    return pd.concat(frames, ignore_index=True), sources


def iso(data, format: str = "auto", drop_outliers: bool = False,
        uncertainty=None, standard: str = standards.DEFAULT) -> IsoResult:
    """ISO 230-2 figures of every test (ISO 230-2:2014 clause 2; ``features.iso230``).

    Parameters
    ----------
    data : str, path-like, DataFrame or list of them
        One or more readings files (``read_tests``), or frames ``read`` returned.
    format : str
        Input layout of a file, ``"auto"`` to recognise it.
    drop_outliers : bool
        Leave the readings flagged as outliers out of the figures (default: flag, keep).
    uncertainty : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget (``experiments/data/paper_uncertainty.toml``): adds the expanded
        uncertainties ``U_A_um, U_E_um, U_M_um, U_R_um, U_B_um`` of every test, at its own
        measuring length and runs per direction (``features.uncertainty.with_uncertainty``).
        Linear axes only.
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
    from features import iso230

    check_params(PARAMETERS, {"data": data, "format": format, "drop_outliers": drop_outliers,
                              "uncertainty": uncertainty, "standard": standard}, "iso")
    record = standards.standard(standard)
    from features import uncertainty as unc

    budget = None if uncertainty is None else unc.checked_budget(uncertainty)
    readings, sources = read_tests(data, format)
    flagged = iso230.outliers(readings)
    outliers = readings.loc[flagged]
    used = readings.loc[~flagged] if drop_outliers else readings
    targets = iso230.per_target(used)
    figures = iso230.axis_figures(used, targets)
    if budget is not None:
        figures = unc.with_uncertainty(figures, targets, budget)
    result = IsoResult(targets=targets, figures=figures, outliers=outliers,
                       dropped=drop_outliers, budget=budget, standard=record,
                       readings=readings, sources=sources)
    action = "dropped" if drop_outliers else "kept; dropping outliers leaves it out"
    for r in outliers.itertuples():
        text = (f"outlier ({action}): test {r.test_id} target {r.target:g} direction "
                f"{r.direction} cycle {r.cycle}: deviation {r.deviation_um:.3f}")
        result.notes.append(text)
        note(text)
    if budget is not None and budget.arithmetic == "paper":
        text = ("uncertainty: the budget's [paper] lengths describe its own test; U is "
                "evaluated in the ISO arithmetic at each test's measuring length")
        result.notes.append(text)
        note(text)
    return result
