"""Registry and serving: the registered versions' tags, the champion rule (forecasting skill
against persistence, only among versions trained on the same data), the pyfunc signature and
output, and a registered fleet model served by ``mlflow models serve`` on loopback."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import warnings
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest

import backlash as bl
from pipeline.tracking import model_registry
from pipeline.tracking import runs as tracking

NAME = model_registry.REGISTERED_NAME
# a small fleet: 2 machines x 2 axes, 6 visits, one feed and dwell, 3 cycles (under a second)
FLEET = {"fleet": {"machines": 2, "axes": ["X", "Y"], "visits": 6, "adjust_at": []},
         "plan": {"feeds_mm_min": [1000.0], "dwells_s": [3.0], "repeats": 1, "cycles": 3}}
PLAN_KEYS = ["machine_id", "axis", "target"]


def quiet(function, *args, **kwargs):
    """``function(*args, **kwargs)`` with the product's notes (warnings) silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return function(*args, **kwargs)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Readings of visits 1-5 of the small fleet and the plan of visit 6 (targets, operating
    hours and feed; no machine temperature, which a wear map may go without)."""
    sim = bl.simulate(preset="fleet", config=FLEET, seed=0)
    readings = sim.readings
    last = readings["visit"] == "06"
    plan = (readings[last & (readings["method"] == "pendulum")]
            .groupby(PLAN_KEYS, as_index=False)[["operating_hours", "feed_mm_min"]].first())
    return readings[~last].reset_index(drop=True), plan


@pytest.fixture(scope="module")
def wear_map(fleet, tmp_path_factory):
    """The recommended predictor trained on the fleet and written to a model directory."""
    result = quiet(bl.train, fleet[0], track=False)  # logged by each test
    result.write(tmp_path_factory.mktemp("fleet-model") / "wear-map")
    return result


def logged_version(result) -> tuple[dict, object]:
    """Log ``result`` (train or compare) in-process; its answer and registered version."""
    logged = quiet(tracking.log_result, result)
    return logged, mlflow.MlflowClient().get_model_version(NAME, logged["version"])


# --------------------------------------------------------------------------- tags
def test_fleet_version_carries_axes_predictor_target_data_and_skill(wear_map):
    logged, version = logged_version(wear_map)
    tags = version.tags
    assert tags["predictor"] == "wear-map" and tags["target_kind"] == wear_map.target_kind
    assert tags["data_sha256"] == wear_map.parameters["data_sha256"]
    assert tags["machines"] == "M01,M02" and tags["n_axes"] == "4"
    assert tags["axes"] == "M01/X,M01/Y,M02/X,M02/Y"
    # five visits: three origins of a rolling-origin backtest on the training data
    run = mlflow.MlflowClient().get_run(logged["run_id"])
    skill = float(tags["backtest_skill"])
    assert run.data.metrics["backtest_skill"] == pytest.approx(skill)
    persistence = run.data.metrics["backtest_persistence_rmse_um"]
    assert skill == pytest.approx(1 - run.data.metrics["backtest_rmse_um"] / persistence,
                                  abs=1e-4)


def test_skill_is_na_with_its_reason(fleet):
    readings = fleet[0]
    constant = quiet(bl.train, readings, model="constant", track=False)
    assert logged_version(constant)[1].tags["backtest_skill"] == (
        "n/a: constant does not forecast a plan")
    two_visits = quiet(bl.train, readings[readings["visit"] <= "02"], track=False)
    assert logged_version(two_visits)[1].tags["backtest_skill"] == (
        "n/a: 2 visit(s) in the training data; the backtest needs at least 3")


def test_long_lists_are_cut_with_a_count():
    axes = [f"M{m:02d}/{a}" for m in range(1, 41) for a in "XYZ"]
    text = model_registry.compact_list(axes, "axes", limit=60)
    assert len(text) <= 60 and text.startswith("M01/X,M01/Y,") and text.endswith(",... (120 axes)")
    assert model_registry.compact_list(["M1/X", "M1/Y"], "axes") == "M1/X,M1/Y"


# --------------------------------------------------------------------------- signature
def test_signature_lists_the_plan_columns_the_wear_map_uses(wear_map):
    _, version = logged_version(wear_map)
    served = mlflow.pyfunc.load_model(f"models:/{NAME}/{version.version}")
    inputs = served.metadata.signature.inputs
    estimator = wear_map.trained.estimator
    features = wear_map.trained.feature_names_
    unused = [f for f in features if f not in estimator.used_features_]
    # the inputs it uses, then, optional, the others it has a trained range of (a value
    # outside it is flagged, as predict flags it); no deviation is required
    assert inputs.input_names() == ["machine_id", "axis", *estimator.used_features_, *unused]
    assert "deviation_up_um" in unused
    assert inputs.required_input_names() == [
        "machine_id", "axis", *[f for f in estimator.used_features_ if f != "machine_temp_c"]]
    assert inputs.optional_input_names() == [*estimator.conditions_, *unused]
    assert estimator.conditions_ == ["machine_temp_c"]
    outputs = served.metadata.signature.outputs
    assert outputs.input_names() == ["backlash_um", "backlash_low_um", "backlash_high_um",
                                     "extrapolated", "borrowed"]
    assert [t.name for t in outputs.input_types()][-2:] == ["string", "string"]


def test_a_network_signature_keeps_the_deviations(fleet, tmp_path):
    result = quiet(bl.train, fleet[0], model="ridge", track=False)
    result.write(tmp_path / "ridge")
    spec = result.tracking_record().model["signature"]
    names = [c["name"] for c in spec["inputs"]]
    # the machine axis optional (given, it is checked against what the model covers)
    assert names == ["machine_id", "axis", *result.trained.feature_names_]
    assert "deviation_up_um" in names
    assert [c["name"] for c in spec["inputs"] if not c["required"]] == ["machine_id", "axis"]
    assert spec["outputs"] == ["backlash_um", "extrapolated"]


# --------------------------------------------------------------------------- champion rule
def version_on(client, digest: str, skill: float | None, rmse: float) -> str:
    """A finished train run (``data_sha256``, ``test_rmse_um``) and a model version tagged as
    ``log_model`` tags it."""
    with tracking.run("train", f"skill {skill}") as run:
        mlflow.log_params({"data_sha256": digest})
        mlflow.log_metric("test_rmse_um", rmse)
    try:
        client.create_registered_model(NAME)
    except mlflow.exceptions.MlflowException:
        pass  # exists
    tags = {"data_sha256": digest,
            "backtest_skill": f"{skill:.4f}" if skill is not None else "n/a: no forecast"}
    return client.create_model_version(NAME, f"runs:/{run.info.run_id}/model",
                                       run.info.run_id, tags=tags).version


def promote(version: str, digest: str, skill: float | None, rmse: float) -> bool:
    return tracking.promote_if_best(version, digest, rmse, skill)


def champion(client) -> str:
    return client.get_model_version_by_alias(NAME, model_registry.CHAMPION).version


def test_higher_skill_on_the_same_data_takes_the_champion():
    client = tracking.client()
    a, b = "a" * 64, "b" * 64
    good = version_on(client, a, 0.40, rmse=0.5)
    assert promote(good, a, 0.40, 0.5) and champion(client) == good
    worse = version_on(client, a, 0.10, rmse=0.3)  # lower held-out RMSE, less skill
    assert not promote(worse, a, 0.10, 0.3) and champion(client) == good
    better = version_on(client, a, 0.55, rmse=0.6)
    assert promote(better, a, 0.55, 0.6) and champion(client) == better
    # another data set never takes the first data set's champion, however skilled
    other = version_on(client, b, 0.99, rmse=0.01)
    assert not promote(other, b, 0.99, 0.01) and champion(client) == better


def test_a_version_without_skill_never_displaces_one_with_skill():
    client = tracking.client()
    a = "a" * 64
    unskilled = version_on(client, a, None, rmse=0.2)
    assert promote(unskilled, a, None, 0.2)  # the first on the data: champion
    skilled = version_on(client, a, -0.1, rmse=0.9)  # any skill beats none
    assert promote(skilled, a, -0.1, 0.9) and champion(client) == skilled
    precise = version_on(client, a, None, rmse=0.01)
    assert not promote(precise, a, None, 0.01) and champion(client) == skilled


def test_trainings_promote_by_skill_and_never_across_data_sets(fleet, wear_map):
    readings = fleet[0]
    constant = quiet(bl.train, readings, model="constant", track=False)
    logged, _ = logged_version(constant)
    assert logged["champion"]
    logged, forecaster = logged_version(wear_map)  # same data, with a skill
    assert logged["champion"] and champion(tracking.client()) == forecaster.version
    fewer = quiet(bl.train, readings[readings["visit"] <= "04"], track=False)  # other data
    logged, _ = logged_version(fewer)
    assert not logged["champion"] and champion(tracking.client()) == forecaster.version


# --------------------------------------------------------------------------- pyfunc output
def test_pyfunc_returns_the_predict_frame_clipped_at_zero(wear_map, fleet):
    _, version = logged_version(wear_map)
    served = mlflow.pyfunc.load_model(f"models:/{NAME}/{version.version}")
    plan = fleet[1]
    answer = served.predict(plan)
    expected = bl.predict(wear_map.files["model"], plan=plan).predictions
    columns = ["backlash_um", "backlash_low_um", "backlash_high_um"]
    assert list(answer.columns) == [*columns, "extrapolated", "borrowed"]
    assert (answer["borrowed"] == "").all()  # every axis of the plan is the fleet's own
    np.testing.assert_allclose(answer[columns], expected[columns], rtol=1e-12)
    assert (answer[columns] >= 0).all().all()
    assert (answer["extrapolated"] == expected["extrapolated"]).all()
    # a target beyond the trained travel, flagged as predict flags it
    far = quiet(served.predict, plan.assign(target=plan["target"] + 5000.0))
    assert (far["extrapolated"] == "target").all()


# --------------------------------------------------------------------------- served over HTTP
def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def serving_unavailable() -> str:
    """Why ``mlflow models serve`` cannot start here (its web server libraries), or ''."""
    missing = [m for m in ("uvicorn", "fastapi") if importlib.util.find_spec(m) is None]
    return f"mlflow models serve needs {', '.join(missing)}" if missing else ""


def venv_env() -> dict:
    """This environment with the virtualenv's bin folder first on PATH: ``mlflow models
    serve --env-manager local`` starts ``uvicorn`` by name."""
    return {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent),
                                                   os.environ.get("PATH", "")])}


def wait_until_up(server: subprocess.Popen, url: str, log: Path, limit_s: float = 180.0):
    """Poll ``GET /ping`` until the server answers; fail with its log if it dies or is slow."""
    deadline = time.monotonic() + limit_s
    while True:
        try:
            with urllib.request.urlopen(f"{url}/ping", timeout=2) as answer:
                if answer.status == 200:
                    return
        except OSError:
            pass
        if server.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"mlflow models serve did not answer within {limit_s:.0f} s:\n"
                        + log.read_text(errors="replace")[-3000:])
        time.sleep(0.5)


def stop(server: subprocess.Popen) -> None:
    """End the server and the worker it started (its own process group, started here)."""
    for sig, wait_s in ((signal.SIGTERM, 30), (signal.SIGKILL, 10)):
        try:
            os.killpg(server.pid, sig)
        except ProcessLookupError:
            break
        try:
            server.wait(timeout=wait_s)
            break
        except subprocess.TimeoutExpired:
            continue


def invoke(url: str, plan: pd.DataFrame) -> pd.DataFrame:
    body = json.dumps({"dataframe_split": plan.to_dict(orient="split")}).encode()
    request = urllib.request.Request(f"{url}/invocations", data=body,
                                      headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=60) as answer:
        return pd.DataFrame(json.loads(answer.read())["predictions"])


def refused(url: str, plan: pd.DataFrame) -> tuple[int, str]:
    """The HTTP status and body of a request the server refuses."""
    try:
        invoke(url, plan)
    except urllib.error.HTTPError as err:
        return err.code, err.read().decode()
    pytest.fail("the server answered a request it should refuse")


@pytest.mark.skipif(bool(serving_unavailable()), reason=serving_unavailable() or "-")
def test_mlflow_models_serve_forecasts_a_plan_over_http(wear_map, fleet, tmp_path):
    _, version = logged_version(wear_map)
    plan = fleet[1]
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = tmp_path / "serve.log"
    with open(log, "w") as out:
        server = subprocess.Popen(
            [str(Path(sys.executable).with_name("mlflow")), "models", "serve",
             "-m", f"models:/{NAME}/{version.version}", "--env-manager", "local",
             "-h", "127.0.0.1", "-p", str(port), "-w", "1"],
            stdout=out, stderr=subprocess.STDOUT, env=venv_env(), start_new_session=True)
        try:
            wait_until_up(server, url, log)
            answer = invoke(url, plan)
            without_feed = invoke(url, plan.drop(columns="feed_mm_min"))
            far = invoke(url, plan.assign(target=plan["target"] + 5000.0))
            negative = refused(url, plan.assign(operating_hours=-480.0))
            rotary = refused(url, plan.assign(axis="A"))
        finally:
            stop(server)
    expected = bl.predict(wear_map.files["model"], plan=plan).predictions
    columns = ["backlash_um", "backlash_low_um", "backlash_high_um"]
    assert list(answer.columns) == [*columns, "extrapolated", "borrowed"]
    assert len(answer) == len(plan)
    np.testing.assert_allclose(answer[columns], expected[columns], rtol=1e-9)
    # the plan's end targets (0 and 350 mm) lie beyond the training's interior ones
    assert (answer["extrapolated"] == expected["extrapolated"]).all()
    assert set(answer["extrapolated"]) == {"", "target"}
    assert (far["extrapolated"] == "target").all()
    # invalid inputs: 400, a body of one line that says what is wrong, no stack trace
    for (status, body), words in ((negative, ("request, row 1, column 'operating_hours': -480 "
                                              "is not operating hours >= 0")),
                                  (rotary, ("M01 A, M02 A: backlash in arcsec, but the model "
                                            "knows only axes in um"))):
        assert status == 400 and "\n" not in body and "Traceback" not in body
        message = json.loads(body)["message"]
        assert words in message, message
        assert "Failed to predict" not in message and len(message) < 300
    # the feed is no input of this wear map (one feed in training): the answer is the same
    np.testing.assert_allclose(without_feed[columns], answer[columns], rtol=1e-12)
