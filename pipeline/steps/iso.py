"""The ISO 230-2 analysis the ``iso`` and ``report`` jobs share: the figures of every test in
one or more readings files, per target and per axis, with the readings far from their
siblings flagged (and, on request, left out). The ``iso`` job returns them with its files
and chart; the ``report`` job prints them, one page per test.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from features import standards
from features.readings import schema
from features.readings.errors import InputError, note
from pipeline.results import Result
from pipeline.steps.source import readings_of

if TYPE_CHECKING:  # a budget is read when one is given: the module stays light for --help
    from features.uncertainty import UncertaintyBudget

# Keys of each test's object in the JSON form (``backlash iso --json``): a public contract.
JSON_KEYS = ("machine_id", "axis", "visit", "test_id", "unit", "A", "A_up", "A_down", "E",
             "E_up", "E_down", "M", "R", "R_up", "R_down", "B", "B_mean")
PER_TARGET_KEYS = ("target", "mean_up", "mean_down", "s_up", "s_down", "B_i", "R_i")
# Columns of the figures table the CLI prints (with the expanded uncertainties [um] of
# ``features.uncertainty.TEST_UNCERTAINTY_KEYS`` when a budget is given).
TABLE_COLUMNS = ("test_id", "unit", "A", "E", "M", "R", "B", "B_mean")


@dataclass
class IsoFigures(Result):
    """ISO 230-2 figures of every test (um, arcsec for rotary axes): what the ``iso`` job
    returns (its ``IsoResult``, with its files) and the ``report`` job prints.

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

    def to_dict(self) -> list[dict]:
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

    @classmethod
    def of(cls, data, format: str = "auto", drop_outliers: bool = False,
           budget: UncertaintyBudget | None = None,
           standard: standards.Standard = standards.ISO230_2):
        """The figures of every test in ``data`` (ISO 230-2:2014 clause 2;
        ``features.iso230``), each outlier a note (and a ``BacklashWarning``).

        Parameters
        ----------
        data : str, path-like, DataFrame or list of them
            One or more readings files (``read_tests``), or frames ``read`` returned.
        format : str
            Input layout of a file, ``"auto"`` to recognise it.
        drop_outliers : bool
            Leave the readings flagged as outliers out of the figures (default: flag, keep).
        budget : features.uncertainty.UncertaintyBudget, optional
            A checked ISO/TR 230-9 budget (``features.uncertainty.checked_budget``): adds the
            expanded uncertainties ``U_A_um, U_E_um, U_M_um, U_R_um, U_B_um`` of every test,
            at its own measuring length and runs per direction
            (``features.uncertainty.with_uncertainty``). Linear axes only.
        standard : features.standards.Standard
            The standard the figures follow (a supported one: ``features.standards.standard``).

        Raises
        ------
        InputError
            Unreadable readings, a budget for a rotary axis.
        """
        from features import iso230
        from features import uncertainty as unc

        readings, sources = read_tests(data, format)
        flagged = iso230.outliers(readings)
        outliers = readings.loc[flagged]
        used = readings.loc[~flagged] if drop_outliers else readings
        targets = iso230.per_target(used)
        figures = iso230.axis_figures(used, targets)
        if budget is not None:
            figures = unc.with_uncertainty(figures, targets, budget)
        result = cls(targets=targets, figures=figures, outliers=outliers,
                     dropped=drop_outliers, budget=budget, standard=standard,
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

