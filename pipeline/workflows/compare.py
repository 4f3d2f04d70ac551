"""Compare predictors on one split, or backtest them as forecasters of the next visit.

>>> import backlash as bl
>>> bl.compare("readings.csv", models=["constant", "ridge"]).table       # doctest: +SKIP
>>> bl.backtest("campaign.csv", models=["wear-map"]).summary            # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from features.readings.errors import InputError, Progress, note, report
from models.serving import registry
from pipeline.results import Result
from pipeline.steps.constraints import StrOptions
from pipeline.steps.parameters import (
    FEATURES,
    FORMAT,
    RANDOM_SEED,
    SPLIT,
    SPLITS,
    TARGET,
    TRUTH,
    Param,
    comma_list,
    each_once,
    readings,
)
from pipeline.workflows import checked

if TYPE_CHECKING:
    import pandas as pd

COLUMNS = ("model", "test_rmse_um", "test_mae_um", "test_r2", "test_mape_pct", "truth_rmse_um")
# cover95_*_pct: the share of the forecast points whose 95 % interval holds the measured value
# and, on twin data, the true one
BACKTEST_COLUMNS = ("model", "origins", "rmse_um", "truth_rmse_um", "cover95_measured_pct",
                    "cover95_true_pct", "skill_vs_persistence")
# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--models", "ridge,knn", "--seed", "2"],
    {"data": "{twin}", "models": ["ridge", "knn"], "seed": 2},
)

PARAMETERS = {
    "data": readings(),
    "format": FORMAT,
    "target": TARGET,
    "features": FEATURES,
    "split": Param((StrOptions((*SPLITS, "backtest")),), SPLIT.help + "; or backtest: train "
                   "on visits <= k, forecast visit k + 1, every k"),
    "truth": TRUTH,
    "seed": RANDOM_SEED,
    "models": Param((list, tuple, None), "comma-separated predictor names (default: all); "
                    + registry.help_text(), parse=comma_list),
    "out": Param((str, os.PathLike, None), "folder for the comparison table and figures",
                 output="folder"),
}


def model_names(models) -> list[str]:
    """``models`` checked against the registry (default: every predictor)."""
    if models is None:
        return registry.names()
    names = list(models)
    if not names:
        raise InputError("expected a non-empty list of predictor names", parameter="models")
    for name in names:
        registry.check_name(name, parameter="models")
    return each_once(names, "models")


@dataclass
class CompareResult(Result):
    """Every predictor fitted and scored on the same split.

    Attributes
    ----------
    table : DataFrame
        One row per predictor, best (lowest ``test_rmse_um``) first: the ``test_*`` and
        ``train_*`` scores, and ``truth_*`` on twin data.
    fits : dict
        Predictor name -> ``models.estimators.training.Fit``.
    noise_floor_um : float
        Standard uncertainty of one measured backlash point [um].
    skills : dict
        Predictor name -> its forecasting skill against persistence
        (``models.condition.backtest.forecast_skill``), which ranks the registered models for the
        champion.
    descriptions : dict
        Predictor name -> the model as plain data, what the registry keeps of it
        (``models.serving.description``).
    """

    table: pd.DataFrame
    fits: dict
    noise_floor_um: float
    target_kind: str
    n_points: int
    parameters: dict = field(default_factory=dict)
    skills: dict = field(default_factory=dict, repr=False)
    descriptions: dict = field(default_factory=dict, repr=False)

    @property
    def best(self) -> str:
        return str(self.table.iloc[0]["model"])

    def write(self, out) -> dict[str, Path]:
        """``comparison.csv`` and, per predictor, its model directory with figures under
        ``models/NAME``."""
        from features.readings.fileio import atomic_path
        from models.serving.description import FIGURES
        from pipeline.reports.model_report import write_figures

        out = Path(out)
        files = {}
        for name, fit in self.fits.items():
            model_dir = registry.save_model(
                fit.trained_model({"data_sha256": self.parameters.get("data_sha256")}),
                out / "models" / name)
            files[name] = model_dir
            files[f"{name} figures"] = write_figures(fit, model_dir / FIGURES)
        out.mkdir(parents=True, exist_ok=True)
        with atomic_path(out / "comparison.csv") as tmp:
            self.table.to_csv(tmp, index=False)
        self.files = {"comparison": out / "comparison.csv", **files}
        return self.files

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan({"target_kind": self.target_kind, "noise_floor_um": self.noise_floor_um,
                          "models": self.table.to_dict("records")})

    def tracking_record(self):
        """A parent run (the table, every model's test RMSE) with one nested run per model
        (registered, from its ``descriptions``); the best (by ``skills``, then test RMSE)
        becomes champion if it beats the champion on the same data."""
        import tempfile

        from models.serving.description import FIGURES
        from pipeline.results import RunRecord

        if "comparison" not in self.files:
            self.write(tempfile.mkdtemp(prefix="backlash-compare-"))
        child_params = {k: self.parameters[k] for k in ("split", "data_sha256", "target_kind",
                                                    "seed")}
        children = [RunRecord(
            experiment="compare", run_name=name, params={"model": name, **child_params},
            metrics=fit.metrics, artifacts=list(self.files[f"{name} figures"]),
            artifact_path=FIGURES,
            model={**self.descriptions[name], "model_dir": str(self.files[name])})
            for name, fit in self.fits.items()]
        return RunRecord(
            experiment="compare", run_name=f"compare {Path(self.parameters['data']).name}",
            params=self.parameters, artifacts=[self.files["comparison"]],
            metrics={f"{r['model']}_test_rmse_um": r["test_rmse_um"]
                     for r in self.table.to_dict("records")},
            children=children, promote=True)


def compare(data, *, models: list[str] | None = None, format: str = "auto",
            target: str = "auto", features: list[str] | None = None, split: str = "random",
            truth=None, seed: int = 0, progress: Progress | None = None):
    """Train every predictor in ``models`` on one hold-out split and score them alike.

    Parameters are those of ``train``; ``models`` lists predictor names (default: all) and
    ``split`` may also be ``'backtest'`` (then this is ``backtest``).

    Returns
    -------
    CompareResult, or BacktestResult for ``split='backtest'``
    """
    import pandas as pd

    from models.condition.backtest import forecast_skill
    from models.estimators.training import fit_model
    from models.serving.description import describe
    from pipeline.steps.model_data import model_data

    if split == "backtest":
        return _backtest(data, models=models, format=format, target=target, features=features,
                         truth=truth, seed=seed, progress=progress)
    names = model_names(models)
    loaded = model_data(data, format, target, features, truth)
    table, rows, fits, skills, descriptions = loaded.table, [], {}, {}, {}
    for i, name in enumerate(names):
        report(progress, i, len(names), name)
        fits[name] = fit_model(table, name, split, seed, loaded.truth, loaded.noise_floor_um,
                               loaded.source)
        skills[name] = forecast_skill(fits[name])
        descriptions[name] = describe(fits[name], loaded.digest, skills[name])
        rows.append({"model": name, **fits[name].metrics})
    report(progress, len(names), len(names), "models")
    result = pd.DataFrame(rows).sort_values("test_rmse_um", kind="stable")
    params = {"data": loaded.source, "data_sha256": loaded.digest, "split": split,
              "target_kind": table.target_kind, "seed": seed, "models": ",".join(names),
              "noise_floor_um": loaded.noise_floor_um}
    return CompareResult(table=result.reset_index(drop=True), fits=fits,
                         noise_floor_um=loaded.noise_floor_um, target_kind=table.target_kind,
                         n_points=len(table.y), parameters=params, skills=skills,
                         descriptions=descriptions)


@dataclass
class BacktestResult(Result):
    """Rolling-origin backtest of every predictor against persistence.

    Attributes
    ----------
    origins : DataFrame
        One row per predictor and origin (``models.condition.backtest.backtest``).
    summary : DataFrame
        Per predictor over all origins, best first (``models.condition.backtest.summary``).
    wear_map : DataFrame or None
        The wear rate along the screw [um per 1000 h] with its 95 % interval, fitted on the
        visits since the last adjustment (when the wear map is compared and can forecast).
    """

    origins: pd.DataFrame
    summary: pd.DataFrame
    wear_map: pd.DataFrame | None
    noise_floor_um: float
    target_kind: str
    n_points: int
    parameters: dict = field(default_factory=dict)

    def write(self, out) -> dict[str, Path]:
        """``backtest.csv``, ``backtest_summary.csv`` and, with a wear map, ``wear_map.csv``
        and ``wear_map.png``."""
        from features.readings.fileio import atomic_path

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        frames = {"backtest": self.origins, "backtest_summary": self.summary,
                  "wear_map": self.wear_map}
        files = {}
        for name, frame in frames.items():
            if frame is not None:
                with atomic_path(out / f"{name}.csv") as tmp:
                    frame.to_csv(tmp, index=False)
                files[name] = out / f"{name}.csv"
        if self.wear_map is not None:
            files["wear_map figure"] = plot_wear_map(self.wear_map, out / "wear_map.png")
        self.files = files
        return files

    def to_dict(self) -> dict:
        from features.readings.fileio import clean_nan

        return clean_nan({"target_kind": self.target_kind, "noise_floor_um": self.noise_floor_um,
                          "split": "backtest", "models": self.summary.to_dict("records"),
                          "origins": self.origins.to_dict("records")})

    def tracking_record(self):
        import tempfile

        import pandas as pd

        from pipeline.results import TrackingRecord

        if not self.files:
            self.write(tempfile.mkdtemp(prefix="backlash-backtest-"))
        metrics = {f"{row['model']}_{k}": v for row in self.summary.to_dict("records")
                   for k, v in row.items() if k != "model" and pd.notna(v)}
        return TrackingRecord(experiment="compare",
                              run_name=f"backtest {Path(self.parameters['data']).name}",
                              params=self.parameters, metrics=metrics,
                              artifacts=list(self.files.values()))


# a plain function (``bl.backtest``), not a job the runner checks: checked against compare's
# table
@checked(PARAMETERS, "data", "models", "format", "target", "features", "truth", "seed")
def backtest(data, *, models: list[str] | None = None, format: str = "auto",
             target: str = "auto", features: list[str] | None = None, truth=None,
             seed: int = 0, progress: Progress | None = None) -> BacktestResult:
    """Forecast every visit k + 1 from the visits <= k (each predictor and persistence).

    Parameters are those of ``compare``. An adjustment restarts the wear clock (a drop in
    operating hours, an ``event``, or a downward change point of the per-visit backlash).

    Returns
    -------
    BacktestResult
    """
    return _backtest(data, models=models, format=format, target=target, features=features,
                     truth=truth, seed=seed, progress=progress)


def _backtest(data, *, models, format, target, features, truth, seed,
              progress) -> BacktestResult:
    """``backtest`` on parameters checked already (compare's, by the runner)."""
    from models.condition import backtest as rolling
    from models.estimators.training import visit_series
    from pipeline.steps.model_data import model_data

    names = model_names(models)
    loaded = model_data(data, format, target, features, truth)
    visits, why_not = visit_series(loaded.readings, loaded.stats)
    if visits is None:
        note(f"adjustments from operating hours and events only; {why_not}")
    origins = rolling.backtest(loaded.table, names, loaded.truth, seed, progress=progress,
                               visits=visits)
    params = {"data": loaded.source, "data_sha256": loaded.digest, "split": "backtest",
              "target_kind": loaded.table.target_kind, "seed": seed, "models": ",".join(names),
              "noise_floor_um": loaded.noise_floor_um}
    wear = (wear_rates(loaded.table, loaded.readings, loaded.stats) if "wear-map" in names
            else None)
    return BacktestResult(origins=origins, summary=rolling.summary(origins), wear_map=wear,
                          noise_floor_um=loaded.noise_floor_um,
                          target_kind=loaded.table.target_kind, n_points=len(loaded.table.y),
                          parameters=params)


def wear_rates(table, readings=None, stats=None) -> pd.DataFrame | None:
    """The wear map fitted on the visits since the last adjustment: w(x) with its interval;
    None when the data cannot give a wear rate (one visit). ``stats``: the readings'
    ``features.iso230.per_target`` when already computed."""
    from models.estimators.training import hours_origins, since_adjustment
    from models.serving.registry import with_axes
    from models.wear.wear_map import WearMap, epoch_lines

    kept, clock = since_adjustment(table, readings, stats)
    for line in epoch_lines(clock["series"]):
        note(line)
    model = WearMap().fit(with_axes(kept.X, kept.meta), kept.y,
                          hours_origin=hours_origins(kept, clock["series"]))
    return model.wear_rate_map() if model.can_forecast_ else None


def plot_wear_map(wear: pd.DataFrame, path) -> Path:
    """Wear rate along the screw [um per 1000 h] with its 95 % band."""
    from pipeline.reports.report_page import new_figure, save_figure

    fig = new_figure(6.5, 3.2)
    ax = fig.subplots()
    ax.fill_between(wear["position_mm"], wear["wear_rate_low"], wear["wear_rate_high"],
                    alpha=0.3, label="95 % interval")
    ax.plot(wear["position_mm"], wear["wear_rate_um_per_1000h"], label="wear rate w(x)")
    ax.set_xlabel("position [mm]")
    ax.set_ylabel("wear rate [um / 1000 h]")
    ax.set_title("Where the screw wears, and how fast")
    ax.legend(loc="best")
    return save_figure(fig, path)
