"""The missing-effect workflow's benchmark: twin data in which effects were hidden from the
baseline, nulls, confounded and aliased designs (``models.discovery.benchmark``). Scenarios are
data: a TOML file (default ``experiments/hidden_effect_scenarios.toml``).

>>> import backlash as bl
>>> result = bl.hidden_effects(seeds=1)     # doctest: +SKIP
>>> result.score["named_correctly_pct"]     # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from numbers import Integral
from pathlib import Path

from features.readings.errors import InputError, Progress, report
from models.physics import SHIPPED
from pipeline.results import Result, TrackingRecord
from pipeline.steps.constraints import HasMethods, Interval
from pipeline.steps.parameters import PROGRESS, Param

SCENARIOS = SHIPPED / "hidden_effect_scenarios.toml"  # the product's, whatever the working folder
FILES = {"scenarios": "scenarios.csv", "by_design": "score_by_design.csv", "score": "score.json"}


# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["--scenarios", "{scenarios}", "--seeds", "1", "--out", "{side}/h"],
    {"scenarios": "{scenarios}", "seeds": 1, "out": "{side}/h"},
)

PARAMETERS = {
    "out": Param((str, os.PathLike, None), "output folder for the scenario table",
                 required=True, output="folder"),
    "scenarios": Param((str, os.PathLike, dict, HasMethods(["check"]))),
    "seeds": Param((Interval(Integral, 1, None, closed="left"), None)),
    "progress": PROGRESS,
}


@dataclass
class HiddenEffectsResult(Result):
    """The benchmark's outcome per scenario and its score.

    Attributes
    ----------
    table : DataFrame
        One row per scenario: design, kind, hidden effects, what was named, the outcome
        (correct, ambiguous, missed, wrong, false name), gaps [um] and CPU seconds.
    score : dict
        Summary figures (named correctly, false names on nulls, mean gap shrink...).
    by_design : DataFrame
        The score per generator and design.
    """

    table: object
    score: dict
    by_design: object = field(repr=False)

    def write(self, out) -> dict[str, Path]:
        """``scenarios.csv``, ``score_by_design.csv`` and ``score.json``."""
        from features.readings.fileio import atomic_path, write_json

        paths = {role: Path(out) / name for role, name in FILES.items()}
        with atomic_path(paths["scenarios"]) as tmp:
            self.table.to_csv(tmp, index=False)
        with atomic_path(paths["by_design"]) as tmp:
            self.by_design.to_csv(tmp, index=False)
        write_json(paths["score"], self.score)
        self.files = paths
        return paths

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan(self.score)

    def tracking_record(self) -> TrackingRecord:
        """One run in experiment ``hidden-effects``: the score as metrics, the files."""
        score = {k: v for k, v in self.to_dict().items() if v is not None}
        return TrackingRecord("hidden-effects", "hidden-effect benchmark", metrics=score,
                              artifacts=list(self.files.values()))


def hidden_effects(scenarios=SCENARIOS, *, seeds: int | None = None,
                   progress: Progress | None = None) -> HiddenEffectsResult:
    """Benchmark the missing-effect workflow on twin data in which effects were hidden.

    Parameters
    ----------
    scenarios : str, path, dict or models.discovery.benchmark.Scenarios
        Scenario file (TOML); default: the shipped
        ``experiments/hidden_effect_scenarios.toml``.
    seeds : int, optional
        Seeds per design (seeds 1 to this number); default the scenario file's seeds.
    progress : callable, optional
        ``progress(done, total, what)``, told as each scenario starts.

    Returns
    -------
    HiddenEffectsResult
    """
    from models.discovery import benchmark as bench

    given_as_file = isinstance(scenarios, (str, os.PathLike))
    try:
        spec = bench.read_scenarios(scenarios)
        expanded = bench.expand(spec, None if seeds is None else tuple(range(1, seeds + 1)))
    except InputError as err:
        if given_as_file or err.parameter is not None:
            raise
        raise InputError(err.message, column=err.column, parameter="scenarios") from None
    table = bench.run(expanded, progress=lambda items: _reported(items, progress))
    return HiddenEffectsResult(table, bench.score(table), bench.score_by_design(table))


def _reported(scenarios: list, progress: Progress | None):
    """The scenarios one by one, telling ``progress`` as each starts."""
    for done, scenario in enumerate(scenarios):
        report(progress, done, len(scenarios), scenario["name"])
        yield scenario
    report(progress, len(scenarios), len(scenarios), "done")
