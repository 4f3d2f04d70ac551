"""Simulate: the feed-drive twin runs ISO 230-2 test campaigns and writes readings and truth.

The twin (``models.physics``) produces a readings table in the same schema as a laser does, so
everything downstream treats simulated and measured data alike, and it records the truth: the
lost motion and every effect's contribution per test, target and direction, and per visit the
operating hours, b0, the wear and the event (adjustment, failure).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path

from features.readings.errors import InputError
from models.physics import PRESETS
from pipeline.results import Result
from pipeline.steps.constraints import Interval
from pipeline.steps.parameters import SEED, Param, python_only

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["--preset", "compensation", "--out", "{side}/sim"],
    {"preset": "compensation", "out": "{side}/sim"},
)

PARAMETERS = {
    # its own help: the command line lists the presets found in experiments/presets/ (checked
    # against them by ``load_config``, not by the parser)
    "preset": Param((str, None), f"a shipped campaign: {', '.join(PRESETS)} (default: the "
                    "paper's plan on one axis)"),
    "config": Param((str, os.PathLike, dict, "models.physics.campaign.Campaign", None),
                    metavar="FILE.toml"),
    "seed": Param(SEED),
    "out": Param((str, os.PathLike, None), "output folder", required=True, output="folder"),
    "traces": Param(("boolean",)),
    "days": Param((Interval(Integral, 1, 3650, closed="both"),)),
    "rate_hz": Param((Interval(Real, 100, 1000, closed="both"),)),
    "session_seed": python_only(*SEED, None),
    "compensation": python_only(dict, None),
}


FILES = {"readings": "readings.csv", "truth": "truth.csv", "visits": "truth_visits.csv",
         "parameters": "parameters.json"}


@dataclass
class SimulationResult(Result):
    """A simulated campaign.

    Attributes
    ----------
    readings : DataFrame
        The readings table, as a laser would write it (``SCHEMA.md``).
    truth : DataFrame
        Per test, target and direction: the true lost motion and every effect's contribution
        [um], and the wear at the target [um].
    visits : DataFrame
        Per machine, axis and visit: date, operating hours [h], b0 [um], local wear [um], the
        lost motion at reference conditions [um] and the event.
    parameters : dict
        The full configuration, the seed, the targets [mm] and the reference conditions.
    config : Campaign
        The configuration as typed data.
    """

    readings: object  # pandas.DataFrame
    truth: object
    visits: object
    parameters: dict
    config: object = field(repr=False, default=None)  # models.physics.campaign.Campaign

    def write(self, out) -> dict[str, Path]:
        """The four files into folder ``out`` together: written into a temporary folder, then
        renamed into place (a failure leaves none of them)."""
        from features.readings import write_readings
        from features.readings.fileio import write_json

        written = write_together(out, {
            FILES["readings"]: lambda path: write_readings(self.readings, path),
            FILES["truth"]: lambda path: self.truth.to_csv(path, index=False),
            FILES["visits"]: lambda path: self.visits.to_csv(path, index=False),
            FILES["parameters"]: lambda path: write_json(path, self.parameters)})
        self.files = {role: written[name] for role, name in FILES.items()}
        return self.files

    def summary(self) -> str:
        """One line: readings, tests and the measuring system."""
        return (f"{len(self.readings)} readings in {self.readings['test_id'].nunique()} tests "
                f"({self.parameters['config']['system']} measuring system)")

    def to_dict(self) -> dict:
        return {"readings": len(self.readings), "tests": int(self.readings["test_id"].nunique()),
                "system": self.parameters["config"]["system"], "seed": self.parameters["seed"],
                "files": {role: str(path) for role, path in self.files.items()}}


def simulate(config=None, preset: str | None = None, seed: int = 0,
             session_seed: int | None = None, compensation: dict | None = None,
             traces: bool = False, days: int = 30, rate_hz: float = 200.0):
    """Simulate a test campaign on the feed-drive twin, or (``traces``) its controller traces.

    Parameters
    ----------
    config : str, Path, dict or Campaign, optional
        A campaign TOML file (docs/simulate.md); its values apply on top of the preset's.
    preset : str, optional
        A shipped campaign (``models.physics.PRESETS``: the files in
        ``experiments/presets/``); default the paper's plan on one axis.
    seed : int
        Random seed: the same configuration and seed give the same numbers.
    session_seed : int, optional
        Re-measure the same machines (same ``seed``) in a new session: new run conditions
        and noise.
    compensation : dict, optional
        (machine_id, axis) -> controller model applied to the commanded path
        (``models.physics.controller``); the random draws do not depend on it.
    traces : bool
        Simulate controller traces instead of a campaign (``models.physics.traces``): three axes
        of one machine, motor encoder and load scale, wear growing, one axis adjusted; written
        to ``traces/`` and ``traces_truth.csv`` in the output folder.
    days : int
        With ``traces``: logged days (1-3650).
    rate_hz : float
        With ``traces``: sampling rate [Hz] (100-1000).

    Returns
    -------
    SimulationResult or TraceSimulationResult
        Readings, truth per test and per visit, and the parameters; ``write(out)`` writes
        ``readings.csv``, ``truth.csv``, ``truth_visits.csv`` and ``parameters.json``. With
        ``traces`` the traces and their truth; ``write(out)`` writes ``traces/`` and
        ``traces_truth.csv``.
    """
    from models.physics.campaign import load_config
    from models.physics.campaign import simulate as run_twin

    _one_kind({"config": config, "preset": preset, "session_seed": session_seed,
               "compensation": compensation, "traces": traces, "days": days,
               "rate_hz": rate_hz})
    if traces:
        return _traces(seed, days, rate_hz)
    campaign = load_config(config, preset=preset)
    sim = run_twin(campaign, seed, compensation=compensation, session_seed=session_seed)
    return SimulationResult(_as_text(sim.readings), _as_text(sim.truth), sim.visits,
                            sim.parameters, config=campaign)


CAMPAIGN_ONLY = ("config", "preset", "session_seed", "compensation")
TRACES_ONLY = ("days", "rate_hz")


def _one_kind(given: dict) -> None:
    """A campaign's parameters with ``traces``, or the traces' without it, would be ignored:
    refused instead."""
    if given["traces"]:
        name = next((n for n in CAMPAIGN_ONLY if given[n] is not None), None)
        if name is not None:
            raise InputError("applies to a test campaign, not to controller traces (--traces)",
                             parameter=name)
        return
    import inspect

    defaults = inspect.signature(simulate).parameters
    name = next((n for n in TRACES_ONLY if given[n] != defaults[n].default), None)
    if name is not None:
        raise InputError("applies to controller traces (--traces) only",
                         parameter=name)


def _as_text(frame):
    """The twin holds names as categories (a fleet's millions of readings repeat a few
    names); a user gets them as text, as ``read`` gives them, since other tools (MLflow's
    schema checks, order comparisons) refuse categories."""
    import pandas as pd

    names = [c for c in frame.columns if isinstance(frame[c].dtype, pd.CategoricalDtype)]
    return frame.astype(dict.fromkeys(names, "str")) if names else frame


@dataclass
class TraceSimulationResult(Result):
    """Controller traces of the twin (``models.physics.traces``) and their truth.

    Attributes
    ----------
    trace : DataFrame
        The trace table (docs/data-contract.md section 10).
    truth : DataFrame
        Per machine axis and day: the true lost motion [um] and the event.
    """

    trace: object
    truth: object
    seed: int = 0

    def write(self, out) -> dict[str, Path]:
        """``traces/`` (a Parquet dataset partitioned by machine, axis and date) and
        ``traces_truth.csv`` into folder ``out``, renamed into place together."""
        from features.traces.io import write_dataset

        written = write_together(out, {
            "traces": lambda path: write_dataset(self.trace, path),
            "traces_truth.csv": lambda path: self.truth.to_csv(path, index=False)})
        self.files = {"traces": written["traces"], "truth": written["traces_truth.csv"]}
        return self.files

    def summary(self) -> str:
        return (f"{len(self.trace)} samples of {self.truth['axis'].nunique()} axes over "
                f"{self.truth['date'].nunique()} days")

    def to_dict(self) -> dict:
        return {"samples": len(self.trace), "days": int(self.truth["date"].nunique()),
                "seed": self.seed, "files": {k: str(v) for k, v in self.files.items()}}


def write_together(out, writers: dict) -> dict[str, Path]:
    """Each ``writers[name](path)`` into a temporary folder beside ``out``, then every file
    (or folder) renamed into ``out`` (a failure leaves none of them); returns name -> path."""
    import shutil

    from features.readings.fileio import temp_folder

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_folder(out)
    try:
        for name, write in writers.items():
            write(tmp / name)
        out.mkdir(exist_ok=True)
        for name in writers:
            if (out / name).is_dir():  # a folder output replaces the one of an earlier run
                shutil.rmtree(out / name)
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {name: out / name for name in writers}


def _traces(seed: int, days: int, rate_hz: float) -> TraceSimulationResult:
    """``simulate(traces=True)``'s traces: three axes of one machine logged a minute a day at
    ``rate_hz`` for ``days`` days, with motor encoder and load scale, wear growing and one
    axis adjusted (``models.physics.traces.TraceCampaign``)."""
    from models.physics.traces import TraceCampaign, simulate_traces

    trace, truth = simulate_traces(TraceCampaign(days=days, rate_hz=rate_hz), seed)
    return TraceSimulationResult(trace, truth, seed=seed)
