"""What a model may answer for: a saved model records the machine axes and units it was trained
on; ``predict`` and the served model refuse rows of other machine axes (one line, exit 2 / HTTP
400), except a fleet model forecasting another axis of its unit, which says how it borrowed;
both take their scope and extrapolation flags from one check (``models.serving.signature.assess``).
Coverage figures name what they cover; a NaN at train time names its test."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.cli import main
from pipeline.tracking import model_registry
from pipeline.tracking import runs as tracking

NAME = model_registry.REGISTERED_NAME
# a small fleet: 2 machines x 2 axes, 5 visits, two feeds and dwells (inputs the wear map
# has a trained range of; it does not use the dwell), 3 cycles (about a second)
FLEET = {"fleet": {"machines": 2, "axes": ["X", "Y"], "visits": 5, "adjust_at": []},
         "plan": {"feeds_mm_min": [500.0, 1000.0], "dwells_s": [3.0, 5.0], "repeats": 1,
                  "cycles": 3}}
PLAN_KEYS = ["machine_id", "axis", "target"]


def quiet(function, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return function(*args, **kwargs)


def noted(function, *args, **kwargs):
    """``function(*args, **kwargs)`` and the product's notes it issued."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = function(*args, **kwargs)
    return result, [str(w.message) for w in caught if issubclass(w.category, BacklashWarning)]


@pytest.fixture(scope="module")
def sim():
    return bl.simulate(preset="fleet", config=FLEET, seed=0)


@pytest.fixture(scope="module")
def data(sim):
    """Readings of visits 1-4 and the plan of visit 5 for M01 X (targets, hours, feed, dwell)."""
    readings = sim.readings
    last = readings["visit"] == "05"
    plan = (readings[last & (readings["method"] == "pendulum") & (readings["machine_id"] == "M01")
                     & (readings["axis"] == "X")]
            .groupby(PLAN_KEYS, as_index=False)[["operating_hours", "feed_mm_min", "dwell_s"]]
            .first())
    inner = plan["target"].between(plan["target"].min(), plan["target"].max(),
                                   inclusive="neither")
    return readings[~last].reset_index(drop=True), plan[inner].reset_index(drop=True)


@pytest.fixture(scope="module")
def one_axis(data, tmp_path_factory):
    """A wear map of M01 X alone, written to a model directory."""
    readings = data[0]
    mine = readings[(readings["machine_id"] == "M01") & (readings["axis"] == "X")]
    result = quiet(bl.train, mine.reset_index(drop=True), track=False)
    result.write(tmp_path_factory.mktemp("one-axis") / "wear-map")
    return result


@pytest.fixture(scope="module")
def fleet_model(data, tmp_path_factory):
    """A wear map of the whole fleet (4 linear axes), written to a model directory."""
    result = quiet(bl.train, data[0], track=False)
    result.write(tmp_path_factory.mktemp("fleet") / "wear-map")
    return result


def served(result):
    """``result``'s model logged and registered as ``train`` logs it, loaded through MLflow
    (its signature decides which columns reach the model)."""
    logged = quiet(tracking.log_result, result)
    return mlflow.pyfunc.load_model(f"models:/{NAME}/{logged['version']}"), logged["version"]


# --------------------------------------------------------------------------- the record
def test_a_saved_model_records_its_machines_axes_and_units(one_axis, fleet_model, tmp_path):
    scope = json.loads((one_axis.files["model"] / "model.json").read_text())["scope"]
    assert scope == {"machines": ["M01"], "axes": [{"machine_id": "M01", "axis": "X",
                                                    "unit": "um"}], "units": ["um"]}
    loaded = bl.load_model(fleet_model.files["model"]).meta["scope"]
    assert loaded["machines"] == ["M01", "M02"] and loaded["units"] == ["um"]
    assert [(a["machine_id"], a["axis"]) for a in loaded["axes"]] == [
        ("M01", "X"), ("M01", "Y"), ("M02", "X"), ("M02", "Y")]
    rotary = bl.simulate(preset="fleet", seed=0, config={
        **FLEET, "fleet": {**FLEET["fleet"], "machines": 1, "axes": ["X", "A"]}}).readings
    mixed = quiet(bl.train, rotary, model="constant", track=False)
    mixed.write(tmp_path / "constant")
    scope = bl.load_model(tmp_path / "constant").meta["scope"]
    assert scope["units"] == ["um", "arcsec"]
    assert {(a["axis"], a["unit"]) for a in scope["axes"]} == {("X", "um"), ("A", "arcsec")}
    # a unit that is not its axis's is refused at loading, one line
    meta = json.loads((tmp_path / "constant" / "model.json").read_text())
    meta["scope"]["axes"][0]["unit"] = "um" if meta["scope"]["axes"][0]["axis"] == "A" else "arcsec"
    (tmp_path / "constant" / "model.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="'scope' gives axis"):
        bl.load_model(tmp_path / "constant")
    # a model of both units answers a row without its axis only when it says which
    with pytest.raises(InputError, match="covers axes in um and arcsec .*: each row needs "
                                         "machine_id and axis"):
        bl.predict(mixed.trained, plan=pd.DataFrame({"target": [100.0]}))


# --------------------------------------------------------------------------- predict refuses
def test_predict_refuses_a_rotary_axis_from_a_linear_model(one_axis, data, tmp_path, capsys):
    plan = data[1].assign(axis="A")
    plan.to_csv(tmp_path / "rotary.csv", index=False)
    out = tmp_path / "pred.csv"
    assert main(["predict", str(one_axis.files["model"]), str(tmp_path / "rotary.csv"),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert ("M01 A: backlash in arcsec, but the model knows only axes in um: it was trained on "
            "M01 X (um)") in err
    assert not out.exists()


@pytest.mark.parametrize("change, first", [
    ({"machine_id": "M02"}, "M02 X"), ({"axis": "Y"}, "M01 Y")])
def test_predict_refuses_a_machine_axis_a_one_axis_model_was_not_trained_on(
        one_axis, data, change, first):
    plan = data[1].copy()
    plan.loc[2:, list(change)] = list(change.values())
    with pytest.raises(InputError) as err:
        bl.predict(one_axis.files["model"], plan=plan)
    assert str(err.value) == (f"plan, row 3, column 'axis': {first} is not among the machine "
                              "axes the model was trained on: M01 X (um); it answers for those "
                              "only")


def test_a_model_of_several_axes_refuses_new_tests_of_another_machine(data, tmp_path):
    readings = data[0]
    ridge = quiet(bl.train, readings, model="ridge", track=False)
    stranger = readings[readings["machine_id"] == "M02"].assign(machine_id="M09")
    with pytest.raises(InputError, match="M09 X is not among the machine axes the model was "
                                         r"trained on: M01 X, M01 Y, M02 X, M02 Y \(um\)"):
        bl.predict(ridge.trained, stranger.reset_index(drop=True))
    assert len(quiet(bl.predict, ridge.trained, readings).predictions) > 0


def test_a_model_saved_before_its_scope_was_recorded_answers_for_nothing(
        one_axis, fleet_model, data, tmp_path, capsys):
    old = tmp_path / "old"
    shutil.copytree(one_axis.files["model"], old)
    meta = json.loads((old / "model.json").read_text())
    del meta["scope"]
    (old / "model.json").write_text(json.dumps(meta))
    data[1].to_csv(tmp_path / "plan.csv", index=False)
    assert main(["predict", str(old), str(tmp_path / "plan.csv"),
                 "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "does not record which machine axes it was trained on" in err
    assert "train it again" in err and not (tmp_path / "p.csv").exists()
    # a fleet model saved before it lists its axes: what it covers is known
    fleet_old = tmp_path / "fleet-old"
    shutil.copytree(fleet_model.files["model"], fleet_old)
    meta = json.loads((fleet_old / "model.json").read_text())
    del meta["scope"]
    (fleet_old / "model.json").write_text(json.dumps(meta))
    assert len(quiet(bl.predict, fleet_old, plan=data[1]).predictions) == len(data[1])
    with pytest.raises(InputError, match="backlash in arcsec, but the model knows only axes"):
        bl.predict(fleet_old, plan=data[1].assign(axis="A"))


# --------------------------------------------------------------------------- a fleet borrows
def test_a_fleet_model_forecasts_another_axis_of_its_unit_and_says_how(fleet_model, data):
    plan = data[1]
    stranger = pd.concat([plan, plan.assign(machine_id="M09")], ignore_index=True)
    result, notes = noted(bl.predict, fleet_model.trained, plan=stranger)
    borrowed = result.predictions["borrowed"]
    how = "the fleet's distribution of its 4 um axes"
    assert (borrowed[:len(plan)] == "").all() and (borrowed[len(plan):] == how).all()
    line = f"M09 X: not in the model's fleet; forecast from {how} (a wider interval)"
    assert line in notes and line in result.notes
    model, _ = served(fleet_model)
    answer = quiet(model.predict, stranger)
    assert list(answer.columns) == ["backlash_um", "backlash_low_um", "backlash_high_um",
                                    "extrapolated", "borrowed"]
    assert (answer["borrowed"] == borrowed).all()
    np.testing.assert_allclose(answer["backlash_um"], result.predictions["backlash_um"],
                               rtol=1e-12)


# --------------------------------------------------------------------------- one check, both ways
def test_predict_and_the_served_model_flag_and_refuse_the_same_rows(one_axis, data):
    plan = data[1]
    model, _ = served(one_axis)
    rows = {"inside": plan, "dwell 600 s": plan.assign(dwell_s=600.0),
            "fast and far": plan.assign(feed_mm_min=plan["feed_mm_min"] * 20,
                                        target=plan["target"] + 5000.0)}
    flags = {}
    for what, frame in rows.items():
        predicted = quiet(bl.predict, one_axis.files["model"], plan=frame).predictions
        answer = quiet(model.predict, frame)
        assert (answer["extrapolated"] == predicted["extrapolated"]).all(), what
        np.testing.assert_allclose(answer["backlash_um"], predicted["backlash_um"], rtol=1e-12)
        flags[what] = set(answer["extrapolated"])
    assert flags == {"inside": {""}, "dwell 600 s": {"dwell_s"},
                     "fast and far": {"feed_mm_min;target"}}
    for change in ({"axis": "A"}, {"machine_id": "M02"}):
        frame = plan.assign(**change)
        with pytest.raises(InputError) as local:
            bl.predict(one_axis.files["model"], plan=frame)
        with pytest.raises(mlflow.exceptions.MlflowException) as remote:
            model.predict(frame)
        assert local.value.message in str(remote.value) and "request, row 1" in str(remote.value)


def test_mlflow_models_serve_refuses_a_rotary_axis_of_a_one_axis_model(one_axis, data, tmp_path):
    from test_registry_serving import (
        free_port,
        invoke,
        refused,
        serving_unavailable,
        stop,
        venv_env,
        wait_until_up,
    )

    if serving_unavailable():
        pytest.skip(serving_unavailable())
    _, version = served(one_axis)
    plan = data[1]
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = tmp_path / "serve.log"
    with open(log, "w") as out:
        server = subprocess.Popen(
            [str(Path(sys.executable).with_name("mlflow")), "models", "serve",
             "-m", f"models:/{NAME}/{version}", "--env-manager", "local",
             "-h", "127.0.0.1", "-p", str(port), "-w", "1"],
            stdout=out, stderr=subprocess.STDOUT, env=venv_env(), start_new_session=True)
        try:
            wait_until_up(server, url, log)
            dwell = invoke(url, plan.assign(dwell_s=600.0))
            status, body = refused(url, plan.assign(axis="A"))
            other, _ = refused(url, plan.assign(machine_id="M02"))
        finally:
            stop(server)
    assert (dwell["extrapolated"] == "dwell_s").all()
    assert status == other == 400 and "\n" not in body and "Traceback" not in body
    message = json.loads(body)["message"]
    assert message.startswith("request, row 1, column 'axis': M01 A: backlash in arcsec, but "
                              "the model knows only axes in um: it was trained on M01 X (um)")


# --------------------------------------------------------------------------- coverage, NaN
def test_every_coverage_figure_names_what_it_covers(sim, tmp_path, capsys):
    readings = sim.readings
    mine = readings[(readings["machine_id"] == "M01") & (readings["axis"] == "X")]
    mine.to_csv(tmp_path / "r.csv", index=False)
    sim.truth.to_csv(tmp_path / "truth.csv", index=False)
    assert main(["compare", str(tmp_path / "r.csv"), "--split", "backtest", "--models",
                 "wear-map", "--truth", str(tmp_path / "truth.csv"), "--out",
                 str(tmp_path / "bt"), "--json", "--no-track"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)["models"]
    wear = next(row for row in summary if row["model"] == "wear-map")
    assert 0 <= wear["cover95_measured_pct"] <= 100 and 0 <= wear["cover95_true_pct"] <= 100
    assert "coverage_pct" not in captured.out + captured.err
    assert "cover95_measured_pct" in captured.err and "cover95_true_pct" in captured.err
    assert "95 % interval holds the measured value, the true value" in captured.err
    table = pd.read_csv(tmp_path / "bt" / "backtest_summary.csv")
    assert {"cover95_measured_pct", "cover95_true_pct"} <= set(table.columns)
    assert not [c for c in table.columns if "coverage" in c]


def test_a_nan_at_train_time_names_the_test_machine_axis_and_column(data, tmp_path, capsys):
    readings = data[0]
    mine = readings[(readings["machine_id"] == "M02") & (readings["axis"] == "Y")].copy()
    gap = mine["visit"] == "03"
    mine.loc[gap, "machine_temp_c"] = np.nan
    first = gap & (mine["feed_mm_min"] == 500.0) & (mine["dwell_s"] == 3.0)  # its first point
    tests = sorted(mine.loc[first, "test_id"].astype(str).unique())
    mine.to_csv(tmp_path / "r.csv", index=False)
    assert main(["train", str(tmp_path / "r.csv"), "--out", str(tmp_path / "m"),
                 "--no-track"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "column 'machine_temp_c'" in err
    assert "NaN in feature at 24 points of the feature table, the first point 49: machine M02, "\
           "axis Y, visit 03, target 50" in err
    assert f"tests {', '.join(tests)}" in err, err
    assert not (tmp_path / "m").exists()
