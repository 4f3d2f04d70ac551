"""The measurement uncertainty of a positioning test: an ISO/TR 230-9 budget from a TOML file.

>>> import backlash as bl
>>> result = bl.uncertainty("experiments/data/paper_uncertainty.toml")   # doctest: +SKIP
>>> result.u_p_um, result.expanded_um["B"]                                # doctest: +SKIP
(1.4610..., 4.1150...)

The budget is computed in two arithmetics side by side (``features.uncertainty``): ``iso``
(every length-dependent line at the measuring length, root-sum-square) and, when the budget
has a ``[paper]`` table, ``paper`` (the lengths and the linear sum of a published budget).
The budget's ``arithmetic`` key, or the ``arithmetic`` parameter, chooses which one is
reported first; the default is ``iso``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from features import uncertainty as unc
from pipeline.results import Result
from pipeline.steps.constraints import StrOptions
from pipeline.steps.parameters import Param

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{budget}"],
    {"budget": "{budget}"},
)

PARAMETERS = {
    "budget": Param((str, os.PathLike, dict, unc.UncertaintyBudget), flag="BUDGET.toml"),
    "arithmetic": Param((StrOptions(unc.ARITHMETICS), None)),
}


@dataclass
class UncertaintyResult(Result):
    """An uncertainty budget evaluated.

    Attributes
    ----------
    budget : features.uncertainty.UncertaintyBudget
        The budget as read.
    values : features.uncertainty.BudgetValues
        The reported arithmetic: its lines, u_P [um] and expanded uncertainties [um].
    other : features.uncertainty.BudgetValues or None
        The other arithmetic, shown side by side (None when the budget has no ``[paper]``).
    source : str
        Where the budget came from.
    """

    budget: unc.UncertaintyBudget
    values: unc.BudgetValues
    other: unc.BudgetValues | None = None
    source: str = ""
    parameters: dict = field(default_factory=dict)

    @property
    def arithmetic(self) -> str:
        return self.values.arithmetic

    @property
    def u_p_um(self) -> float:
        """u_P [um]: standard uncertainty of one positional deviation at the measuring length."""
        return self.values.u_p_um

    @property
    def expanded_um(self) -> dict:
        """Expanded uncertainties [um] by figure: R_dir (R↑, R↓), B, R, E, M, A."""
        return self.values.expanded_um

    def by_arithmetic(self) -> dict[str, unc.BudgetValues]:
        """Both evaluations by name, the reported one first."""
        both = {self.values.arithmetic: self.values}
        if self.other is not None:
            both[self.other.arithmetic] = self.other
        return both

    def write(self, out) -> dict[str, Path]:
        """``uncertainty.json`` (the ``to_dict`` form) under ``out``."""
        from features.readings.fileio import write_json

        self.files = {"json": write_json(Path(out) / "uncertainty.json", self.to_dict())}
        return self.files

    def to_dict(self) -> dict:
        b = self.budget

        def block(v: unc.BudgetValues) -> dict:
            return {"contributors_um": v.contributors_um, "u_P_um": v.u_p_um,
                    "U_um": dict(v.expanded_um)}

        return {
            "axis": b.axis, "length_mm": b.length_mm, "cycles": b.cycles,
            "coverage_factor": b.coverage_factor, "arithmetic": self.arithmetic,
            **block(self.values),
            "lines": [ln._asdict() for ln in self.values.lines],
            "side_by_side": {name: block(v) for name, v in self.by_arithmetic().items()},
            "notes": list(self.notes),
        }


def uncertainty(budget, *, arithmetic: str | None = None) -> UncertaintyResult:
    """Evaluate an ISO/TR 230-9 uncertainty budget.

    Parameters
    ----------
    budget : str, path, dict or UncertaintyBudget
        The uncertainty budget, a TOML file (e.g. ``experiments/data/paper_uncertainty.toml``;
        read by ``features.uncertainty.read_budget``).
    arithmetic : {'iso', 'paper'}, optional
        The arithmetic to report first, the other shown beside it; default the budget's
        ``arithmetic`` key, else ``iso``. The arithmetic ``paper`` needs the budget's ``[paper]``
        table.

    Returns
    -------
    UncertaintyResult
        The lines of the budget, u_P [um] and the expanded uncertainties [um] of R↑/R↓, B, R,
        E, M and A, in the reported and (where the budget allows) the other arithmetic.

    Raises
    ------
    InputError
        A missing or negative contributor, a unit in the wrong place, an unknown key.
    """
    source = str(budget) if isinstance(budget, (str, os.PathLike)) else "<budget>"
    read = unc.read_budget(budget)
    chosen = arithmetic or read.arithmetic
    values = unc.budget_values(read, chosen)
    others = [a for a in unc.ARITHMETICS if a != chosen and (a != "paper" or read.paper)]
    other = unc.budget_values(read, others[0]) if others else None
    notes = []
    if chosen == "paper":
        notes.append("the paper's arithmetic (lines at the [paper] lengths, not the measuring "
                     "length) is reported first; the ISO arithmetic is shown beside it")
    return UncertaintyResult(budget=read, values=values, other=other, source=source,
                             parameters={"arithmetic": arithmetic}, notes=notes)
