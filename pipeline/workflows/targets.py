"""The backlash targets of a readings table: one value per point (machine, axis, visit, feed,
dwell, repeat and target) with its uncertainty, as the models learn them (docs/backlash.md).

>>> import backlash as bl
>>> result = bl.targets("readings.csv", uncertainty="paper_uncertainty.toml")  # doctest: +SKIP
>>> result.points[["target", "backlash_um", "backlash_U_um"]]                  # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from features import uncertainty as unc
from pipeline.results import Result
from pipeline.steps.parameters import BUDGET, FORMAT, TARGET, Param, readings
from pipeline.steps.source import readings_of, source_of

# Columns of the printed table (those the points have).
TABLE_COLUMNS = ("machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat", "target",
                 "target_kind", "backlash_um", "backlash_u_um", "backlash_U_um")


# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--axis", "Y", "--target", "iso"],
    {"data": "{two}", "axis": "Y", "target": "iso"},
)

PARAMETERS = {
    "data": readings(),
    "format": FORMAT,
    "out": Param((str, os.PathLike, None), "output folder: write targets.csv", output="folder"),
    "target": TARGET,
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
}


@dataclass
class TargetsResult(Result):
    """The backlash points of a readings table.

    Attributes
    ----------
    points : DataFrame
        ``features.targets.backlash_targets``: one row per point, ``backlash_um`` and
        ``backlash_u_um`` [um], with a budget also ``backlash_U_um`` [um] (k of the budget).
    target_kind : str
        'paper', 'iso' or 'mixed' (axes with different definitions).
    target_reason : str
        The evidence for the definition.
    source : str
        Where the readings came from.
    coverage_factor : float or None
        k of the budget, None without one.
    parameters : dict
        The workflow's parameters as given.
    """

    points: object = field(repr=False)
    target_kind: str
    target_reason: str
    source: str
    coverage_factor: float | None = None
    parameters: dict = field(default_factory=dict)

    def write(self, out) -> dict[str, Path]:
        """Write ``targets.csv`` (every column of ``points``) into the folder ``out``."""
        from features.readings.fileio import atomic_path

        path = Path(out) / "targets.csv"
        with atomic_path(path) as tmp:
            self.points.to_csv(tmp, index=False)
        self.files["targets"] = path
        return self.files

    @property
    def unit(self) -> str:
        """Unit of the backlash values: um, or arcsec for rotary axes."""
        from features.readings.schema import unit_of

        return unit_of(self.points["axis"])

    def to_dict(self) -> dict:
        """``target_kind``, ``target_reason``, ``coverage_factor`` (None without a budget),
        ``unit`` and one object per point; NaN becomes None."""
        from features.readings.fileio import clean_nan

        return clean_nan({"target_kind": self.target_kind, "target_reason": self.target_reason,
                          "coverage_factor": self.coverage_factor, "unit": self.unit,
                          "points": self.points.to_dict("records")})

    def table(self, max_rows: int | None = None) -> str:
        """The points as a text table (three decimals; at most ``max_rows`` rows, the first
        and the last, when given)."""
        columns = [c for c in TABLE_COLUMNS if c in self.points.columns]
        return self.points[columns].to_string(index=False, max_rows=max_rows,
                                              float_format=lambda v: f"{v:.3f}")


def targets(data, *, format: str = "auto", target: str = "auto",
            uncertainty=None) -> TargetsResult:
    """Backlash per point of a readings table (``features.targets.backlash_targets``).

    Parameters
    ----------
    data : str, path-like or DataFrame
        A readings file, a fleet store or a frame ``read`` returned.
    format : str, default 'auto'
        Input layout of a file.
    target : {'auto', 'paper', 'iso'}, default 'auto'
        Backlash definition: pendulum minus linear, the ISO reversal value, or chosen per
        machine axis from the measuring-system evidence.
    uncertainty : str, path-like, dict or UncertaintyBudget, optional
        An ISO/TR 230-9 budget, a TOML file (e.g. ``experiments/data/paper_uncertainty.toml``):
        every point gets ``backlash_U_um``, the expanded uncertainty of its backlash
        (``features.targets.point_uncertainty``). Linear axes only.

    Returns
    -------
    TargetsResult

    Raises
    ------
    InputError
        Bad readings or parameters, unpaired tests for ``target='paper'``, an unreadable or
        non-physical budget, a budget for a rotary axis.
    """
    from features.targets import backlash_targets

    budget = None if uncertainty is None else unc.checked_budget(uncertainty)
    readings = readings_of(data, format)
    points = backlash_targets(readings, target, budget)
    return TargetsResult(points, points.attrs["target_kind"], points.attrs["target_reason"],
                         source_of(data, readings),
                         None if budget is None else budget.coverage_factor,
                         {"data": data, "format": format, "target": target,
                          "uncertainty": uncertainty})
