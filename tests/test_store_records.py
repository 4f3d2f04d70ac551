"""Forecasts and compensations recorded in the fleet store, on both engines (the embedded
folder and PostgreSQL on a real server on loopback): what is recorded is what the workflow
returned, recording it again changes nothing, a batch is all or nothing, a store of format 1
reads as having none and is upgraded by its first record, a newer one is refused, a record that
cannot be interpreted is refused, and a password never shows."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import uuid

import numpy as np
import pandas as pd
import pytest
from store_files import REPO, cli, refused, visits

import backlash as bl
from features.readings.errors import InputError
from pipeline.store.base import FORMAT_VERSION, MANIFEST
from pipeline.store.records import (
    RECORD_FORMAT,
    check_compensation,
    check_forecast,
    read_records,
    record,
    record_compensation,
)
from pipeline.workflows.compensate import compensate

PLAN = REPO / "experiments" / "data" / "plan_next_visit.csv"
PASSWORD = "s3cret-Pw"
VISITS = ("01", "02", "03", "04")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A wear map trained on visits 01-04 of the twin's M01 X, with its training store."""
    folder = tmp_path_factory.mktemp("model")
    bl.ingest(visits(folder, which=VISITS), store=folder / "fleet")
    bl.train(folder / "fleet", model="wear-map").write(folder / "model")
    return folder / "model"


@pytest.fixture(params=["folder", pytest.param("postgres", marks=pytest.mark.postgres)])
def store(request, tmp_path) -> str:
    """A store of each engine holding visits 01-04 of M01 X."""
    if request.param == "folder":
        location = str(tmp_path / "fleet")
    else:
        from pg_server import create_database

        location = create_database(request.getfixturevalue("postgres_url"),
                                   f"records_{uuid.uuid4().hex[:10]}")
    bl.ingest(visits(tmp_path, which=VISITS), store=location)
    return location


def only(records: dict, key=("M01", "X")) -> list[dict]:
    assert list(records) == [key]
    return records[key]


# --------------------------------------------------------------------- forecasts


def test_a_forecast_is_recorded_as_predicted_and_once(store, model):
    forecast = bl.predict(model, plan=PLAN, store=store)
    assert (forecast.recorded.added, forecast.recorded.unchanged) == (1, 0)
    again = bl.predict(model, plan=PLAN, store=store)
    assert (again.recorded.added, again.recorded.unchanged) == (0, 1)
    [stored] = only(read_records(store, "forecast"))
    expected = forecast.predictions
    for key in ("target", "backlash_um", "backlash_low_um", "backlash_high_um"):
        np.testing.assert_array_equal(stored["points"][key], expected[key].to_numpy(float))
    assert (stored["visit"], stored["operating_hours"], stored["for_date"]) == ("09", 4320.0,
                                                                              None)
    assert stored["model"] == "wear-map" and stored["model_dir"] == str(model)
    assert stored["model_sha256"] == hashlib.sha256(
        (model / "model.json").read_bytes()).hexdigest()
    rate = bl.load_model(model).estimator.wear_rate_map()
    np.testing.assert_allclose(stored["wear_rate"]["rate"], rate["wear_rate_um_per_1000h"])


def test_a_forecast_of_tests_is_recorded_per_visit_with_its_day(tmp_path, model):
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=VISITS), store=location)
    result = bl.predict(model, location, store=location)
    assert result.recorded.added == len(VISITS)
    stored = only(read_records(location, "forecast"))
    readings = bl.read(location)
    days = readings.groupby("visit")["started_at"].min().dt.date.astype(str)
    assert {r["visit"]: r["for_date"] for r in stored} == days.to_dict()
    hours = readings.groupby("visit")["operating_hours"].mean()
    assert {r["visit"]: r["operating_hours"] for r in stored} == hours.to_dict()
    assert sum(len(r["points"]["target"]) for r in stored) == len(result.predictions)


def test_predict_store_on_the_command_line(tmp_path, model, capsys):
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=VISITS), store=location)
    argv = ["predict", model, PLAN, "--out", tmp_path / "p.csv", "--store", location]
    code, _, err = cli(capsys, argv)
    assert code == 0 and f"1 forecast recorded in {location}" in err, err
    code, _, err = cli(capsys, argv)
    assert code == 0 and f"0 forecasts recorded in {location} (1 already recorded)" in err, err


def test_predict_store_refusals_are_one_line_with_nothing_written(tmp_path, model, capsys):
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=("01",)), store=location)
    anonymous = tmp_path / "plan.csv"
    pd.read_csv(PLAN).drop(columns=["machine_id", "axis"]).to_csv(anonymous, index=False)
    out = tmp_path / "p.csv"
    (tmp_path / "empty").mkdir()
    for store, plan, expected in (
            (tmp_path / "nowhere", PLAN, "--store: holds no store yet"),
            (tmp_path / "empty", PLAN, "--store: holds no store yet"),
            (anonymous, PLAN, "--store: is a file; expected a store folder"),
            (location, anonymous, "column 'machine_id': a forecast is recorded per machine")):
        line = refused(capsys, ["predict", model, plan, "--out", out, "--store", store])
        assert expected in line, line
        assert not out.exists()
    assert read_records(location, "forecast") == {}
    assert not (tmp_path / "nowhere").exists() and not any((tmp_path / "empty").iterdir())


# --------------------------------------------------------------------- compensations


def test_a_compensation_is_recorded_from_the_compensate_result_and_once(store, tmp_path):
    result = compensate(store, controller="csv,fanuc")
    result.write(tmp_path / "comp")
    recorded = record_compensation(store, result)
    assert (recorded.added, recorded.unchanged) == (2, 0)
    assert record_compensation(store, result).added == 0
    stored = only(read_records(store, "compensation"))
    [profile] = result.profiles
    assert sorted(r["controller"] for r in stored) == ["csv", "fanuc"]
    for r in stored:
        np.testing.assert_array_equal(r["table"]["target"], profile.target)
        np.testing.assert_array_equal(r["table"]["error_up_um"], profile.mean_up)
        np.testing.assert_array_equal(r["table"]["error_down_um"], profile.mean_down)
        written = next(w for w in result.written if w["controller"] == r["controller"])
        assert r["reversal_compensation_um"] == written["backlash"]
        assert r["files"] == [str(tmp_path / "comp" / f) for f in written["files"].values()]


def test_compensate_store_option_records_and_fleet_shows_it(tmp_path, capsys):
    store = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=VISITS), store=store)
    out = tmp_path / "comp"
    code, _, err = cli(capsys, ["compensate", store, "--controller", "csv", "--out", out,
                                "--store", store])
    assert code == 0 and any("recorded" in line for line in err), err
    [stored] = only(read_records(store, "compensation"))
    assert stored["controller"] == "csv" and stored["files"] == [str(out / f) for f in
                                                                  sorted(p.name for p in
                                                                         out.iterdir())]
    line = refused(capsys, ["compensate", store, "--controller", "csv", "--out",
                            tmp_path / "other", "--store", tmp_path / "nowhere"])
    assert "holds no store yet" in line and not (tmp_path / "other").exists()


def test_a_result_without_compensation_is_refused():
    with pytest.raises(InputError, match="expected the result of compensate"):
        record_compensation("unused", object())


# --------------------------------------------------------------------- all or nothing


def test_a_batch_with_one_bad_record_records_nothing(store):
    good = compensation_record()
    bad = {**compensation_record(), "axis": "Q"}
    with pytest.raises(InputError, match="axis is 'Q'"):
        record(store, "compensation", [good, bad])
    assert read_records(store, "compensation") == {}
    assert record(store, "compensation", [good, good]).added == 1


def compensation_record(**change) -> dict:
    return {"kind": "compensation", "format": RECORD_FORMAT, "machine_id": "M01", "axis": "X",
            "controller": "csv", "source": "measured", "unit": "um",
            "reversal_compensation_um": 1.5, "interpolation_error_um": None,
            "table": {"target": [0.0, 100.0], "error_up_um": [0.5, -1.0],
                      "error_down_um": [2.0, 0.5]}, "files": ["M01_X.csv"], **change}


def forecast_record(**change) -> dict:
    return {"kind": "forecast", "format": RECORD_FORMAT, "machine_id": "M01", "axis": "X",
            "visit": "09", "for_date": "2026-09-01", "operating_hours": 4320.0,
            "model": "wear-map", "model_dir": None, "model_sha256": None,
            "points": {"target": [50.0, 100.0], "backlash_um": [3.0, 3.5]}, "wear_rate": None,
            **change}


@pytest.mark.parametrize(("change", "expected"), [
    ({"points": {"target": [50.0, 100.0], "backlash_um": [3.0, float("nan")]}},
     "not a finite number"),
    ({"points": {"target": [50.0], "backlash_um": [3.0, 3.5]}}, "not a list of 1 numbers"),
    ({"points": {"target": [50.0, 100.0], "backlash_um": [3.0, -1.0]}}, ">= 0"),
    ({"points": {"target": [50.0], "backlash_um": [3.0], "backlash_low_um": [2.0]}},
     "one bound of the interval"),
    ({"for_date": "2026-13-01"}, "not a date"),
    ({"colour": "red"}, "unknown field(s) colour"),
    ({"format": RECORD_FORMAT + 1}, "record format"),
    ({"model": ""}, "model is ''"),
])
def test_a_forecast_that_cannot_be_interpreted_is_refused(change, expected):
    assert check_forecast(forecast_record())
    with pytest.raises(InputError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        check_forecast(forecast_record(**change))


@pytest.mark.parametrize(("change", "expected"), [
    ({"table": {"target": [100.0, 0.0], "error_up_um": [0.5, -1.0],
                "error_down_um": [2.0, 0.5]}}, "not ascending"),
    ({"unit": "arcsec"}, "not that of axis X"),
    ({"source": "guessed"}, "not measured or predicted"),
    ({"reversal_compensation_um": -0.1}, ">= 0"),
    ({"files": ["ok.csv", 3]}, "not a list of file names"),
])
def test_a_compensation_that_cannot_be_interpreted_is_refused(change, expected):
    assert check_compensation(compensation_record())
    with pytest.raises(InputError, match=expected):
        check_compensation(compensation_record(**change))


# --------------------------------------------------------------------- format versions


def execute(location: str, sql: str, *args) -> list:
    """Run SQL on a store behind backlash's back (the embedded store's manifest or the
    PostgreSQL database; ``?`` marks parameters); the rows of a query."""
    if "://" in location:
        import psycopg

        with psycopg.connect(location, autocommit=True) as conn:
            cursor = conn.execute(sql.replace("?", "%s").replace("meta", "backlash_store")
                                  .replace("compensations", "backlash_compensations")
                                  .replace("forecasts", "backlash_forecasts"), args)
            return cursor.fetchall() if cursor.description else []
    conn = sqlite3.connect(f"{location}/{MANIFEST}", isolation_level=None)
    try:
        return conn.execute(sql, args).fetchall()
    finally:
        conn.close()


def version(location: str) -> str:
    return execute(location, "SELECT value FROM meta WHERE key = 'format_version'")[0][0]


def test_a_store_of_format_1_has_no_records_and_its_first_record_upgrades_it(store, model):
    execute(store, "DROP TABLE forecasts")
    execute(store, "DROP TABLE compensations")
    execute(store, "UPDATE meta SET value = '1' WHERE key = 'format_version'")
    before = bl.read(store)
    assert version(store) == "1"
    assert read_records(store, "forecast") == read_records(store, "compensation") == {}
    bl.predict(model, plan=PLAN, store=store)
    assert len(only(read_records(store, "forecast"))) == 1
    assert read_records(store, "compensation") == {}
    pd.testing.assert_frame_equal(bl.read(store), before)
    assert version(store) == str(FORMAT_VERSION) == "4"
    execute(store, "UPDATE meta SET value = ? WHERE key = 'format_version'",
            str(FORMAT_VERSION + 1))
    with pytest.raises(InputError, match=f"store format {FORMAT_VERSION + 1}"):
        read_records(store, "forecast")
    with pytest.raises(InputError, match="newer backlash"):
        record(store, "compensation", [compensation_record()])


def test_a_record_changed_outside_backlash_is_refused(store):
    record(store, "compensation", [compensation_record()])
    execute(store, "UPDATE compensations SET record = replace(record, '1.5', '2.5')")
    with pytest.raises(InputError, match="does not match its digest"):
        read_records(store, "compensation")
    execute(store, "UPDATE compensations SET record = '{not json'")
    with pytest.raises(InputError, match="cannot be read"):
        read_records(store, "compensation")


# --------------------------------------------------------------------- password


@pytest.mark.postgres
def test_the_password_never_shows_when_recording(postgres_url, tmp_path, model, capsys):
    from pg_server import create_database

    url = create_database(postgres_url, f"records_{uuid.uuid4().hex[:10]}")
    url = url.replace("postgres@", f"postgres:{PASSWORD}@", 1)
    outputs = []
    code, out, err = cli(capsys, ["predict", model, PLAN, "--out", tmp_path / "p.csv",
                                  "--store", url])  # no store yet: an error line
    assert code == 2
    outputs += [out, *err]
    bl.ingest(visits(tmp_path, which=("01", "02")), store=url)
    code, out, err = cli(capsys, ["predict", model, PLAN, "--out", tmp_path / "p.csv",
                                  "--store", url, "--json"])
    assert code == 0
    outputs += [out, *err]
    recorded = record_compensation(url, compensate(url))
    outputs += [recorded.text, repr(recorded)]
    code, out, err = cli(capsys, ["fleet", url, "--json", "--out", tmp_path / "site"])
    outputs += [out, *err, *(p.read_text() for p in (tmp_path / "site").iterdir())]
    assert any("postgres:***@" in text for text in outputs)
    leaked = [text for text in outputs if PASSWORD in text]
    assert not leaked, leaked[:3]
    assert json.loads(out)["axes"][0]["last_compensation"]["controller"] == "csv"
