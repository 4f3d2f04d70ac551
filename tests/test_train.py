"""train / predict / compare on hand-built paired tests: outputs, tracking, bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import pandas as pd
import pytest
from test_targets import ideal_tests

from pipeline.cli import main


@pytest.fixture
def readings_csv(tmp_path):
    path = tmp_path / "readings.csv"
    ideal_tests(direct=True).to_csv(path, index=False)
    return path


def one_error_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines()
           if line.startswith("backlash ")]
    assert len(err) == 1, err
    return err[0]


def test_train_saves_model_figures_and_registers_champion(readings_csv, tmp_path, capsys):
    out = tmp_path / "model"
    assert main(["train", str(readings_csv), "--out", str(out), "--model", "bspline"]) == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["name"] == "bspline" and meta["target_kind"] == "paper"
    assert meta["features"][:3] == ["target", "deviation_down_um", "deviation_up_um"]
    assert {p.name for p in (out / "figures").iterdir()} >= {
        "error_histogram.png", "predictions.png", "regression.png"}
    client = mlflow.MlflowClient()
    champion = client.get_model_version_by_alias("backlash-predictor", "champion")
    run = client.get_run(champion.run_id)
    assert run.data.params["model"] == "bspline" and len(run.data.params["data_sha256"]) == 64
    assert {"test_rmse_um", "test_mae_um", "test_r2", "test_mape_pct"} <= set(run.data.metrics)
    # the registered model serves through MLflow without unpickling anything
    served = mlflow.pyfunc.load_model("models:/backlash-predictor@champion")
    inputs = pd.read_csv(out / "training_inputs.csv").iloc[:4]
    from models.serving.registry import load_model

    # a frame of backlash_um (no interval for bspline), clipped at 0 like `predict`
    answer = served.predict(inputs)
    assert list(answer.columns) == ["backlash_um", "extrapolated"]
    assert (answer["extrapolated"] == "").all()  # the training inputs lie inside their ranges
    assert list(answer["backlash_um"]) == pytest.approx(
        [max(v, 0.0) for v in load_model(out).predict(inputs)])

    pred = tmp_path / "pred.csv"
    assert main(["predict", str(out), str(readings_csv), "--out", str(pred)]) == 0
    table = pd.read_csv(pred)
    assert list(table.columns) == ["machine_id", "axis", "visit", "feed_mm_min", "dwell_s",
                                   "repeat", "target", "backlash_um", "extrapolated"]
    assert len(table) == 3 * 6 and (table["backlash_um"] >= 0).all()


def test_compare_prints_every_model_and_picks_the_best(readings_csv, tmp_path, capsys):
    code = main(["compare", str(readings_csv), "--models", "constant,bspline,ridge",
                 "--out", str(tmp_path / "cmp"), "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    rmse = {m["model"]: m["test_rmse_um"] for m in result["models"]}
    # backlash is set by feed here (1.4 / 2.0 / 3.4 um): ridge on the feed beats a constant
    assert rmse["ridge"] < 0.2 < rmse["constant"]
    assert (tmp_path / "cmp" / "comparison.csv").is_file()


@pytest.mark.parametrize("change, args, words", [
    ("none", ["--model", "transformer"], "unknown model 'transformer'"),
    ("unpaired", ["--target", "paper"], "unpaired linear test"),
    ("one_feed", [], "too few to split"),
    ("none", ["--features", "target,dwell_s"], "feature is constant"),
    ("nan_temp", ["--features", "target,machine_temp_c"], "NaN in feature"),
    ("none", ["--model", "linear-temperature", "--features", "target,feed_mm_min"],
     "predictor 'linear-temperature' needs the input 'machine_temp_c'"),
    ("none", ["--model", "bspline", "--features", "feed_mm_min,machine_temp_c"],
     "predictor 'bspline' needs the input 'target'"),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, change, args, words):
    readings = ideal_tests(direct=True)
    if change == "unpaired":
        readings = readings[readings["test_id"] != "pendulum-500"]
    if change == "one_feed":
        readings = readings[readings["feed_mm_min"] == 200.0]
    if change == "nan_temp":
        readings.loc[readings["feed_mm_min"] == 500.0, "machine_temp_c"] = float("nan")
    path = tmp_path / "r.csv"
    readings.to_csv(path, index=False)
    out = tmp_path / "model"
    assert main(["train", str(path), "--out", str(out), *args]) == 2
    line = one_error_line(capsys)
    assert words in line, line
    assert not out.exists()


def test_forward_split_on_the_twin_beats_the_noise_floor(capsys):
    """Twin data with wear over six visits, trained on the first four: the best model's error
    against the true backlash is at or below the noise floor of one measured target."""
    from pathlib import Path

    data = Path(__file__).parents[1] / "experiments" / "data" / "twin"
    code = main(["compare", str(data / "readings.csv"), "--split", "forward", "--truth",
                 str(data / "truth.csv"), "--models", "effect-model,hybrid,shallow-lm,constant",
                 "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    truth = {m["model"]: m["truth_rmse_um"] for m in result["models"]}
    assert min(truth.values()) <= result["noise_floor_um"]
    assert truth["effect-model"] <= result["noise_floor_um"] < truth["constant"]


def test_default_predictor_fits_saves_and_predicts_without_skops_torch_or_mlflow(tmp_path):
    """The everyday path imports only what it uses: the default predictor saves itself as plain
    data, so fitting, saving, loading and ``backlash predict`` need none of the heavy
    libraries (the time goal is in bench/bench_cli.py)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    # the demo's twin data: several visits, so any default predictor can fit them
    readings_csv = Path(__file__).parents[1] / "experiments" / "data" / "twin" / "readings.csv"
    model, pred = tmp_path / "model", tmp_path / "pred.csv"
    script = "\n".join([
        "import sys",
        "from features.readings import read_readings",
        "from features.table import feature_table",
        "from models.serving import registry",
        "from models.estimators.training import fit_model",
        "from pipeline.cli import main",
        f"table = feature_table(read_readings({str(readings_csv)!r}, 'auto'), target='auto')",
        "fit = fit_model(table, registry.RECOMMENDED)",
        f"registry.save_model(fit.trained_model(), {str(model)!r})",
        f"argv = ['predict', {str(model)!r}, {str(readings_csv)!r}, '--out', {str(pred)!r}]",
        "assert main(argv) == 0",
        "heavy = ('skops', 'torch', 'mlflow', 'matplotlib', 'optuna')",
        "print(','.join(m for m in heavy if m in sys.modules))",
    ])
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip() == "", done.stdout
    assert len(pd.read_csv(pred)) > 0 and pd.read_csv(pred)["backlash_um"].notna().all()


TWIN = Path(__file__).parents[1] / "experiments" / "data" / "twin" / "readings.csv"


def test_the_champions_skill_is_the_jobs_tracked_or_not(monkeypatch):
    """``train`` and ``compare`` compute the forecasting skill that ranks models for the
    champion themselves (``result.skill``, ``result.skills``): the same with ``track=False``
    as with ``track=True``, and what the registered version carries; logging a result computes
    no backtest."""
    import warnings

    import backlash as bl
    from features.readings.errors import BacklashWarning
    from models.condition import backtest
    from pipeline.tracking import runs as tracking

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        untracked = bl.train(TWIN, model="wear-map", track=False)
        tracked = bl.train(TWIN, model="wear-map")
        compared = {track: bl.compare(TWIN, models=["wear-map", "constant"], track=track)
                    for track in (False, True)}
    assert untracked.skill == tracked.skill and untracked.skill["skill"] is not None
    assert compared[False].skills == compared[True].skills
    assert compared[True].skills["wear-map"] == tracked.skill
    assert compared[True].skills["constant"]["skill"] is None  # it does not forecast
    client = mlflow.MlflowClient()
    version = client.get_model_version("backlash-predictor", tracked.tracking["version"])
    assert version.tags["backtest_skill"] == f"{tracked.skill['skill']:.4f}"

    def no_backtest(*args, **kwargs):
        raise AssertionError("logging a result ran a backtest")

    monkeypatch.setattr(backtest, "backtest", no_backtest)
    logged = tracking.log_result(untracked)
    assert tracking.client().get_model_version("backlash-predictor", logged["version"]).tags[
        "backtest_skill"] == f"{untracked.skill['skill']:.4f}"
    record = compared[False].tracking_record()
    assert {c.run_name: c.model["backtest"] for c in record.children} == compared[False].skills
