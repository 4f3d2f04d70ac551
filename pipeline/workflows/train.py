"""Train one backlash predictor on paired tests: score it on a hold-out split, save it.

>>> import backlash as bl
>>> result = bl.train("readings.csv", model="wear-map")      # doctest: +SKIP
>>> result.metrics["test_rmse_um"]                             # doctest: +SKIP
>>> result.write("model/")                                     # doctest: +SKIP
>>> model = bl.load_model("model/")                            # doctest: +SKIP
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import InputError, note
from models.serving import registry
from pipeline.results import Result
from pipeline.steps.parameters import (
    BUDGET,
    FEATURES,
    FORMAT,
    RANDOM_SEED,
    SPLIT,
    TARGET,
    TRUTH,
    Param,
    readings,
)

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{twin}", "--model", "ridge", "--out", "{side}/m"],
    {"data": "{twin}", "model": "ridge", "out": "{side}/m"},
)

PARAMETERS = {
    "data": readings(),
    "format": FORMAT,
    "target": TARGET,
    "features": FEATURES,
    "split": SPLIT,
    "truth": TRUTH,
    "seed": RANDOM_SEED,
    "out": Param((str, os.PathLike, None), "model directory to write", required=True,
                 output="folder"),
    "model": Param((str, None),  # names checked by the registry
                   f"predictor (default: {registry.RECOMMENDED}): {', '.join(registry.names())}"
                   "; backlash compare lists what each does", metavar="NAME"),
    "uncertainty": Param(BUDGET, metavar="BUDGET.toml"),
}


@dataclass
class TrainResult(Result):
    """A trained predictor with its scores.

    Attributes
    ----------
    model : str
        Registry name of the predictor.
    fit : models.estimators.training.Fit
        The fitted estimator, its split and predictions.
    trained : models.serving.registry.TrainedModel
        What ``write`` saves as a model directory (and ``predict`` takes).
    metrics : dict
        ``test_*``, ``train_*`` (RMSE and MAE [um], R^2, MAPE [%]), on twin data
        ``truth_*`` and ``noise_floor_um`` and, with an uncertainty budget, the test error
        against U(B) (``models.estimators.evaluation.against_uncertainty``).
    parameters : dict
        What the run logs as its parameters (model, split, target, features, data hash...).
    skill : dict
        Forecasting skill against persistence from a backtest on the training table
        (``models.condition.backtest.forecast_skill``): ``skill`` (None for a predictor that does not
        forecast, or too few visits, with the ``reason``), ``rmse_um``,
        ``persistence_rmse_um``, ``origins``. It ranks registered models for the champion.
    description : dict
        The model as plain data, what the registry keeps of it (``models.serving.description``).
    """

    model: str
    fit: object
    trained: object
    metrics: dict
    parameters: dict
    n_points: int = 0
    target_kind: str = ""
    target_reason: str = ""
    figures: list[Path] = field(default_factory=list)
    skill: dict = field(default_factory=dict)
    description: dict = field(default_factory=dict, repr=False)

    def repr_items(self) -> dict[str, str]:
        rmse = self.metrics.get("test_rmse_um")
        return {"model": repr(self.model), "points": str(self.n_points),
                "target": repr(self.target_kind),
                **({"test_rmse_um": f"{rmse:.4g}"} if rmse is not None else {})}

    def write(self, out) -> dict[str, Path]:
        """Save the model directory ``out`` (``model.json``, the estimator, the training
        inputs) and the figures of the fit in ``out/figures``."""
        self.save(out)
        self.draw()
        return self.files

    def save(self, out) -> Path:
        """The first half of ``write``: the model directory ``out`` without its figures."""
        self.files = {"model": registry.save_model(self.trained, out)}
        return self.files["model"]

    def draw(self) -> list[Path]:
        """The second half of ``write``: the figures of the fit in the saved model directory's
        ``figures`` folder."""
        from models.serving.description import FIGURES
        from pipeline.reports.model_report import write_figures

        return self.drawn(write_figures(self.fit, self.files["model"] / FIGURES,
                                        U_um=self.metrics.get("U_B_um")))

    def drawn(self, figures: list) -> list[Path]:
        """Take ``figures`` (paths ``draw`` wrote, maybe in another process) as the result's."""
        self.figures = [Path(p) for p in figures]
        self.files.update({p.stem: p for p in self.figures})
        return self.figures

    def to_dict(self) -> dict:
        from models.estimators.evaluation import resolution_verdict

        verdict = ({"resolution": resolution_verdict(self.metrics)}
                   if "U_B_um" in self.metrics else {})
        return {"model": self.model, "target_kind": self.target_kind, "metrics": self.metrics,
                **verdict,
                **({"model_dir": str(self.files["model"])} if "model" in self.files else {})}

    def tracking_record(self):
        """Params, metrics, the figures and the model (``description`` with its directory:
        registered; champion if its ``skill`` is best on the same data). A result not written
        yet is written to a temporary folder first; one saved but not drawn yet (``save``
        without ``draw``) has no figures in its record: ``figures_record`` logs them once
        drawn."""
        import tempfile

        from models.serving.description import FIGURES
        from pipeline.results import RunRecord

        if "model" not in self.files:
            self.write(Path(tempfile.mkdtemp(prefix="backlash-train-")) / self.model)
        return RunRecord(
            experiment="train", run_name=f"train {self.model}", params=self.parameters,
            metrics=self.metrics, artifacts=list(self.figures), artifact_path=FIGURES,
            model={**self.description, "model_dir": str(self.files["model"])}, promote=True)

    def figures_record(self):
        """The figures alone, for the run ``tracking_record`` started before they were drawn:
        the model is logged while they are drawn."""
        from models.serving.description import FIGURES
        from pipeline.results import TrackingRecord

        return TrackingRecord(experiment="train", run_name=f"train {self.model}",
                              artifacts=list(self.figures), artifact_path=FIGURES)


def train(data, *, model: str | None = None, format: str = "auto", target: str = "auto",
          features: list[str] | None = None, split: str = "random", truth=None,
          seed: int = 0, uncertainty=None) -> TrainResult:
    """Fit one predictor on the backlash points of paired tests and score it on a hold-out.

    Parameters
    ----------
    data : str, path-like or DataFrame
        Readings file (any input format) or a readings frame from ``read``.
    model : str, optional
        Predictor name (``models.serving.registry.PREDICTORS``); default the recommended wear map.
    format : str
        Input layout of ``data`` (default: detect).
    target : {'auto', 'paper', 'iso'}
        Backlash definition: pendulum minus linear (paper), the ISO reversal value (iso) or
        chosen from the measuring-system evidence (auto).
    features : list of str, optional
        Feature-table columns to use (default: the paper's inputs the data supply, plus
        ``dwell_s`` and ``operating_hours``).
    split : {'random', 'forward'}
        Hold-out: a random 15 % (paper) or the later visits (forward).
    truth : str, path-like or DataFrame, optional
        The twin's truth table (``simulate``): also score against the true backlash.
    seed : int
        Random seed of the split and of the estimator.
    uncertainty : str, path-like or dict, optional
        An ISO/TR 230-9 budget (``experiments/data/paper_uncertainty.toml``): score the test
        error against U(B), the median over the data's tests at each one's measuring length
        (``measurement_U_B_um``). Linear axes only.

    Returns
    -------
    TrainResult
        Notes say which visits a wear map's clock uses (it restarts at an adjustment); its
        ``skill`` is the forecasting skill that ranks it for the champion.

    Raises
    ------
    InputError
        Bad data or parameters, an unreadable or non-physical budget, a budget for a rotary
        axis's data.
    """
    from features.uncertainty import checked_budget
    from models.condition.backtest import forecast_skill
    from models.estimators.training import fit_model, since_adjustment
    from models.serving.description import describe
    from pipeline.steps.model_data import model_data

    name = model or registry.RECOMMENDED
    registry.check_name(name)
    budget = None if uncertainty is None else checked_budget(uncertainty)
    loaded = model_data(data, format, target, features, truth)
    U_B = None if budget is None else measurement_U_B_um(loaded.stats, budget)
    table, clock, origins, usage = loaded.table, None, {}, []
    if registry.predictor(name).wear_clock:  # the wear clock restarts at an adjustment
        from models.estimators.training import hours_origins
        from models.wear.wear_clock import usage_rates
        from models.wear.wear_map import epoch_lines

        usage = usage_rates(loaded.readings)  # turns a date into hour-counter readings

        table, clock = since_adjustment(table, loaded.readings, loaded.stats)
        origins = hours_origins(table, clock["series"])
        for line in [*epoch_lines(clock["series"]), clock["change_points"]]:
            if line and line != "searched":
                note(line)
    fit = fit_model(table, name, split, seed, loaded.truth, loaded.noise_floor_um,
                    loaded.source, hours_origin=origins)
    for line in borrowing_lines(fit.trained_model().meta.get("axes", [])):
        note(line)
    metrics = fit.metrics
    resolution = {}
    if U_B is not None:
        from models.estimators.evaluation import against_uncertainty, resolution_verdict

        y, test = fit.table.y.to_numpy(float), fit.test_index
        metrics = {**metrics, **against_uncertainty(y[test], fit.predicted_um[test], U_B)}
        resolution = {"uncertainty": {
            "U_B_um": U_B, "test_abs_error_p95_um": metrics["test_abs_error_p95_um"],
            "test_rmse_um": metrics["test_rmse_um"], "verdict": resolution_verdict(metrics)}}
    digest = loaded.digest
    meta = {"split": split, "data_sha256": digest, "data": loaded.source,
            "noise_floor_um": loaded.noise_floor_um, "target_reason": table.reason,
            "seed": seed, **({"wear_clock": clock} if clock else {}),
            **({"usage": usage} if usage else {}), **resolution}
    params = {"model": name, "split": split, "target_kind": table.target_kind,
              "features": ",".join(table.X.columns), "n_train": len(fit.train_index),
              "n_test": len(fit.test_index), "data": loaded.source, "data_sha256": digest,
              "seed": seed}
    skill = forecast_skill(fit)
    return TrainResult(model=name, fit=fit, trained=fit.trained_model(meta),
                       metrics=metrics, parameters=params, n_points=len(loaded.table.y),
                       target_kind=table.target_kind, target_reason=table.reason,
                       skill=skill, description=describe(fit, digest, skill))


def measurement_U_B_um(stats, budget) -> float:
    """U(B) [um] of the data's backlash measurement: the median over its tests of the budget's
    expanded uncertainty of B at each test's measuring length and runs per direction
    (``features.uncertainty.per_test_um``); ``stats`` the readings' per-target statistics
    (``features.iso230.per_target``).

    Raises
    ------
    InputError
        Readings of a rotary axis, or no test with a measuring length (one target only).
    """
    import numpy as np

    from features.uncertainty import per_test_um

    U = per_test_um(stats, budget)["U_B_um"].to_numpy(float)
    if not np.isfinite(U).any():
        raise InputError("no test has two targets: the budget has no measuring length to be "
                         "evaluated at", parameter="uncertainty")
    return float(np.nanmedian(U))


def borrowing_lines(axes: list[dict]) -> list[str]:
    """A note per machine axis whose wear rate rests mostly on the fleet: one visit since its
    wear clock restarted (its rate comes from the fleet alone)."""
    return [f"{a['machine_id']} {a['axis']}: one visit since its wear clock restarted; its wear "
            "rate comes from the fleet's (a wider interval)" for a in axes if a["visits"] < 2]


def load_model(path):
    """A model directory written by ``train`` (``TrainResult.write``), checked before anything
    is built (``models.serving.registry.load_model``); ``predict`` takes it."""
    return registry.load_model(path)
