"""The model jobs from Python (``import backlash as bl``): train, predict, compare, backtest and
the MLflow adapter on the demo twin data; declared parameter constraints; the predictor
registry that the CLI and the docs read; no lock file left in the working folder."""

from __future__ import annotations

import importlib
import warnings
from pathlib import Path

import mlflow
import pandas as pd
import pytest

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from models.serving import persistence, registry
from pipeline.cli import main
from pipeline.tracking import runs as tracking

REPO = Path(__file__).resolve().parents[1]
TWIN = REPO / "experiments" / "data" / "twin"
READINGS = TWIN / "readings.csv"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The recommended wear map trained from Python and written as a model directory."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        result = bl.train(READINGS, truth=TWIN / "truth.csv", split="forward", track=False)
    result.write(tmp_path_factory.mktemp("model") / "wear-map")
    return result


def test_train_from_python_scores_writes_and_loads(trained):
    assert trained.model == registry.RECOMMENDED
    assert {"test_rmse_um", "train_rmse_um", "truth_rmse_um"} <= set(trained.metrics)
    assert trained.metrics["truth_rmse_um"] < 1.0
    files = trained.files
    assert (files["model"] / "model.json").is_file() and files["regression"].is_file()
    model = bl.load_model(files["model"])
    assert model.name == "wear-map" and model.meta["split"] == "forward"
    assert trained.to_dict()["metrics"] == trained.metrics


def test_train_takes_a_validated_frame_as_well_as_a_path(trained):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        again = bl.train(bl.read(READINGS), truth=pd.read_csv(TWIN / "truth.csv",
                                                              dtype={"visit": str}),
                         split="forward")
    assert again.metrics["test_rmse_um"] == pytest.approx(trained.metrics["test_rmse_um"])


def test_a_hand_made_frame_is_refused_naming_data():
    with pytest.raises(InputError) as err:
        bl.train(pd.DataFrame({"target": [1.0, 2.0]}))
    assert err.value.parameter == "data"


def test_predict_from_readings_and_from_a_plan_has_named_interval_columns(trained, tmp_path):
    model_dir = trained.files["model"]
    from_readings = bl.predict(model_dir, READINGS)
    assert from_readings.has_interval and from_readings.model == "wear-map"
    frame = from_readings.predictions
    assert {"backlash_um", "backlash_low_um", "backlash_high_um"} <= set(frame)
    assert (frame["backlash_low_um"] <= frame["backlash_um"]).all()
    readings = bl.read(READINGS)
    last = readings[readings["visit"] == readings["visit"].max()]
    plan = last.groupby(["machine_id", "axis", "visit", "feed_mm_min", "dwell_s", "repeat",
                         "target"], as_index=False)["operating_hours"].first()
    plan.to_csv(tmp_path / "plan.csv", index=False)
    forecast = bl.predict(bl.load_model(model_dir), plan=tmp_path / "plan.csv")
    assert len(forecast.predictions) == len(plan) and forecast.has_interval
    written = forecast.write(tmp_path / "forecast.csv")["predictions"]
    assert len(pd.read_csv(written)) == len(plan)
    assert forecast.tracking_record().params["model"] == "wear-map"


def test_predict_needs_readings_or_a_plan(trained):
    with pytest.raises(InputError) as err:
        bl.predict(trained.files["model"])
    assert err.value.parameter == "data"


def test_compare_and_backtest_from_python():
    result = bl.compare(READINGS, models=["constant", "bspline"], split="forward",
                        truth=TWIN / "truth.csv")
    assert list(result.table["model"]) == sorted(
        ["constant", "bspline"], key=lambda m: result.fits[m].metrics["test_rmse_um"])
    assert result.best == result.table.iloc[0]["model"]
    steps = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        backtest = bl.backtest(READINGS, models=["wear-map", "constant"],
                               progress=lambda done, total, what: steps.append((done, total)))
    assert set(backtest.summary["model"]) == {"wear-map", "constant", "persistence"}
    assert backtest.wear_map is not None and steps[-1][0] == steps[-1][1] > 0


def test_log_result_logs_a_compare_with_nested_runs_and_a_champion(tmp_path):
    result = bl.compare(READINGS, models=["constant", "bspline"], track=False)  # logged below
    result.write(tmp_path / "cmp")
    logged = tracking.log_result(result)
    assert set(logged["children"]) == {"constant", "bspline"} and logged["champion"]
    client = mlflow.MlflowClient()
    parent = client.get_run(logged["run_id"])
    assert parent.data.params["models"] == "constant,bspline"
    assert "constant_test_rmse_um" in parent.data.metrics
    champion = client.get_model_version_by_alias(tracking.REGISTERED_NAME, tracking.CHAMPION)
    assert champion.run_id == logged["children"][result.best]["run_id"]
    child = client.get_run(champion.run_id)
    assert child.data.tags["mlflow.parentRunId"] == logged["run_id"]


@pytest.mark.parametrize("function, kwargs, parameter", [
    ("train", {"split": "sideways"}, "split"),
    ("train", {"target": "best"}, "target"),
    ("train", {"seed": -1}, "seed"),
    ("train", {"model": "transformer"}, "model"),
    ("train", {"features": []}, "features"),
    ("train", {"features": ["target", "target"]}, "features"),
    ("train", {"format": "excel"}, "format"),
    ("compare", {"models": ["constant", "wearmap"]}, "models"),
    ("compare", {"split": "sideways"}, "split"),
    ("backtest", {"models": []}, "models"),
    ("tune", {"folds": 1}, "folds"),
    ("tune", {"storage": "redis://x"}, "storage"),
])
def test_declared_constraints_name_the_parameter(function, kwargs, parameter):
    with pytest.raises(InputError) as err:
        getattr(bl, function)(READINGS, **kwargs)
    assert err.value.parameter == parameter


def test_predictor_needing_an_input_names_features():
    with pytest.raises(InputError, match="needs the input 'target'") as err:
        bl.train(READINGS, model="bspline", features=["feed_mm_min", "operating_hours"])
    assert err.value.parameter == "features"


def test_registry_records_drive_the_cli_and_match_the_save_format(tmp_path):
    """One record per predictor: the CLI's help lists every name, and each record's save
    format is what ``save_estimator`` writes for a fitted predictor."""
    parser = importlib.import_module("pipeline.cli").build_parser()
    help_text = parser.commands["train"].format_help() + parser.commands["compare"].format_help()
    compact = "".join(help_text.split())  # argparse may break a name at its hyphen
    assert all(name in compact for name in registry.names())
    assert [row["name"] for row in registry.table()] == registry.names()
    from features.table import feature_table

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        data = feature_table(bl.read(READINGS))
    kinds = {"json": {"json", "self"}, "torch": {"self"}, "parts": {"self"}, "skops": {"skops"}}
    for record in registry.PREDICTORS.values():
        estimator = registry.make(record.name)
        if hasattr(estimator, "max_epochs"):
            estimator.set_params(max_epochs=3)
        if record.save_format in ("parts", "torch") and record.name != "wear-map-hybrid":
            continue  # networks: fitted and saved by the estimator tests; kept fast here
        estimator.fit(data.X, data.y)
        spec = persistence.save_estimator(estimator, tmp_path / record.name, "estimator")
        assert spec["format"] in kinds[record.save_format], record.name
    assert registry.predictor("wear-map").wear_clock and registry.predictor("wear-map").forecasts
    with pytest.raises(InputError) as err:
        registry.make("wearmap")
    assert err.value.parameter == "model"


@pytest.mark.parametrize("job", ["train", "predict", "compare", "tune"])
def test_commands_are_short_and_share_the_workflow_summary(job):
    command = importlib.import_module(f"pipeline.commands.{job}")
    from pipeline.workflows import workflow

    assert workflow(job).name == job and workflow(job).function.__module__.startswith(
        "pipeline.")
    lines = Path(command.__file__).read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 120


def test_train_leaves_no_lock_file_in_the_working_folder(tmp_path, monkeypatch, capsys):
    """The default store is ``mlflow.db`` in the working folder; the lock guarding its
    creation lives in the temporary folder."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI")
    monkeypatch.setenv("BACKLASH_ARTIFACTS", str(tmp_path / "artifacts"))
    monkeypatch.setattr(tracking, "_ready", set())
    data = tmp_path / "readings.csv"
    bl.read(READINGS).to_csv(data, index=False)
    assert main(["train", str(data), "--out", "model", "--model", "constant"]) == 0
    assert (tmp_path / "mlflow.db").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["artifacts", "mlflow.db", "model",
                                                          "readings.csv"]
    assert tracking.lock_path(tmp_path / "mlflow.db").parent != tmp_path


def test_tune_from_python_then_logged_by_the_adapter(tmp_path):
    from test_targets import ideal_tests

    data = tmp_path / "readings.csv"
    ideal_tests(direct=True).to_csv(data, index=False)
    steps = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        result = bl.tune(data, trials=2, folds=2, storage=f"sqlite:///{tmp_path / 'o.db'}",
                         progress=lambda done, total, what: steps.append(done),
                         track=False)  # logged below
    assert result.trials == {"complete": 2} and steps == [1, 2]
    assert result.to_dict()["best_cv_rmse_um"] == result.best_cv_rmse_um > 0
    logged = tracking.log_result(result)
    assert set(logged["children"]) == {"trial 0", "trial 1"}
    run = mlflow.MlflowClient().get_run(logged["children"]["trial 0"]["run_id"])
    assert run.data.tags["mlflow.parentRunId"] == logged["run_id"]
    assert run.data.tags["optuna_trial"] == "0" and "cv_rmse_um" in run.data.metrics
