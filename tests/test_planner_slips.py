"""What a hurried maintenance planner gets wrong, and the word each slip gets: a test dated
ahead, a misspelled column, a corrected file for stored tests, a store path that does not
exist, limits that apply to nothing, a visit typed without its leading zero. Each is one line
with exit 2 or a note naming it; nothing is half-written."""

from __future__ import annotations

import datetime as dt
import json
import sqlite3
import uuid
import warnings

import pandas as pd
import pytest
from store_files import cli, refused, visit_frame, visits

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from pipeline.store import open_store

TODAY = dt.datetime.now(dt.UTC).date()
AHEAD = TODAY + dt.timedelta(days=91)  # three months ahead


def quiet(job, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        return job(*args, **kwargs)


def notes_of(job, *args, **kwargs) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BacklashWarning)
        job(*args, **kwargs)
    return [str(w.message) for w in caught if issubclass(w.category, BacklashWarning)]


def dated_ahead(folder, visit: str = "07"):
    """Visit 06 of the twin again as visit ``visit``, started three months from today."""
    frame = visit_frame("06")
    shift = pd.Timestamp(AHEAD, tz="UTC") - pd.to_datetime(frame["started_at"], utc=True).min()
    frame = frame.assign(visit=visit, test_id=frame["test_id"].str.replace("v06", f"v{visit}"),
                         started_at=pd.to_datetime(frame["started_at"], utc=True) + shift)
    frame = frame.drop(columns=["measured_at"])
    path = folder / f"ahead_v{visit}.csv"
    frame.to_csv(path, index=False)
    return path, frame["test_id"].iloc[0]


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    """A store holding the twin's six visits of M01 X (the last in August 2026)."""
    folder = tmp_path_factory.mktemp("six")
    store = folder / "fleet"
    quiet(bl.ingest, visits(folder), store=store)
    return store


# --------------------------------------------------------------------- 1. future dates


def test_a_test_dated_after_today_is_refused_at_ingest_naming_file_test_and_date(tmp_path,
                                                                                capsys):
    path, _ = dated_ahead(tmp_path)
    line = refused(capsys, ["ingest", path, "--store", tmp_path / "fleet"])
    assert str(path) in line and "test 'M01-X-v07-" in line
    assert f"started on {AHEAD.isoformat()}" in line
    assert f"after today ({TODAY.isoformat()})" in line and "--allow-future" in line
    assert not (tmp_path / "fleet").exists()
    code, _, err = cli(capsys, ["ingest", path, "--store", tmp_path / "fleet",
                                "--allow-future"])
    assert code == 0 and any("started after today" in e and "--allow-future" in e
                             for e in err), err


def test_a_view_as_of_today_leaves_a_test_dated_ahead_out(six, tmp_path, capsys):
    """The twin's axis was last measured in August: 90 days later it is overdue. A visit
    dated three months ahead must not make it look measured."""
    ahead = dated_ahead(tmp_path)[0]
    frame = bl.validate(pd.concat([bl.read(six), bl.read(ahead)], ignore_index=True))
    view = quiet(bl.fleet, frame).to_dict()["axes"][0]
    assert "overdue" in view["alerts"] and view["last_visit"] == "06", view["alerts"]
    store = tmp_path / "fleet"
    quiet(bl.ingest, visits(tmp_path), store=store)
    quiet(bl.ingest, ahead, store=store, allow_future=True)
    code, out, err = cli(capsys, ["fleet", store, "--no-track", "--json"])
    axis = json.loads(out)["axes"][0]
    assert code == 3  # the overdue alert
    assert "overdue" in axis["alerts"] and axis["last_visit"] == "06", axis["alerts"]
    assert any(f"18 test(s) started after {TODAY.isoformat()} left out" in e for e in err)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)
        drifted = bl.drift(store).to_dict()["series"][0]
    assert drifted["visits"][-1] == "06"


# --------------------------------------------------------------------- 2. unknown columns


def test_a_misspelled_column_is_refused_at_ingest_with_the_closest_name(tmp_path, capsys):
    frame = visit_frame("01")
    typo = tmp_path / "typo.csv"
    frame.rename(columns={"machine_temp_c": "machine_tmp_c"}).to_csv(typo, index=False)
    line = refused(capsys, ["ingest", typo, "--store", tmp_path / "fleet"])
    assert str(typo) in line and "machine_tmp_c: did you mean machine_temp_c?" in line
    assert "--allow-unknown-columns" in line and not (tmp_path / "fleet").exists()
    # the corrected file goes in: the first one left nothing that would contradict it
    fixed = tmp_path / "fixed.csv"
    frame.to_csv(fixed, index=False)
    code, _, err = cli(capsys, ["ingest", fixed, "--store", tmp_path / "fleet"])
    assert code == 0, err
    assert bl.read(tmp_path / "fleet")["machine_temp_c"].notna().all()
    # kept out on request, with the hint in the note
    code, _, err = cli(capsys, ["ingest", typo, "--store", tmp_path / "other",
                                "--allow-unknown-columns"])
    assert code == 0 and any("machine_tmp_c: did you mean machine_temp_c?" in e
                             and "left out of the store" in e for e in err), err


def test_other_commands_keep_the_column_and_name_the_closest_one(tmp_path, capsys):
    typo = tmp_path / "typo.csv"
    visit_frame("01").rename(columns={"ambient_temp_c": "ambient_temp"}).to_csv(typo,
                                                                                index=False)
    code, _, err = cli(capsys, ["iso", typo])
    assert code == 0 and any("ambient_temp: did you mean ambient_temp_c?" in e for e in err)
    assert "ambient_temp" in bl.read(typo).columns  # convert passes it on as before


# --------------------------------------------------------------------- 3. --replace


def corrected(tmp_path, visit: str = "02"):
    frame = visit_frame(visit)
    frame.loc[frame["test_id"] == frame["test_id"].iloc[0], "deviation_um"] += 0.7
    path = tmp_path / f"corrected_v{visit}.csv"
    frame.to_csv(path, index=False)
    return path, frame["test_id"].iloc[0]


@pytest.fixture(params=["folder", pytest.param("postgres", marks=pytest.mark.postgres)])
def new_store(request, tmp_path):
    if request.param == "folder":
        return str(tmp_path / "fleet")
    from pg_server import create_database

    return create_database(request.getfixturevalue("postgres_url"),
                           f"slips_{uuid.uuid4().hex[:10]}")


def test_replace_puts_corrected_readings_in_place_and_the_audit_keeps_why(new_store, tmp_path,
                                                                           capsys):
    store = new_store
    quiet(bl.ingest, visits(tmp_path, which=("01", "02")), store=store)
    path, test = corrected(tmp_path)
    old = bl.read(store)
    # without a reason, and for a test the store lacks: one line, nothing changed
    assert "--reason" in refused(capsys, ["ingest", "--replace", path, "--store", store])
    new_test = tmp_path / "v03.csv"
    visit_frame("03").to_csv(new_test, index=False)
    assert "is not in the store; --replace replaces stored tests only" in refused(
        capsys, ["ingest", "--replace", new_test, "--store", store, "--reason", "r"])
    pd.testing.assert_frame_equal(bl.read(store), old)
    code, out, err = cli(capsys, ["ingest", "--replace", path, "--store", store, "--reason",
                                  "laser compensation was off", "--json"])
    assert code == 0 and json.loads(out)["replaced"] == 1, err
    assert any("1 test(s) replaced (laser compensation was off)" in e for e in err)
    now = bl.read(store)
    mine = now["test_id"] == test
    assert (now.loc[mine, "deviation_um"].to_numpy()
            == pytest.approx(old.loc[old["test_id"] == test, "deviation_um"] + 0.7))
    pd.testing.assert_frame_equal(now[~mine].reset_index(drop=True),
                                  old[old["test_id"] != test].reset_index(drop=True))
    rows = audit(store)
    assert [(r["action"], r["test_id"], r["reason"]) for r in rows] == [
        ("replace", test, "laser compensation was off")]
    assert rows[0]["user_name"] and rows[0]["old_sha256"] != rows[0]["sha256"]
    assert bl.check_store(store).ok, bl.check_store(store).problems


def test_check_finds_a_replaced_test_whose_digest_is_not_the_audits(tmp_path):
    store = tmp_path / "fleet"
    quiet(bl.ingest, visits(tmp_path, which=("01", "02")), store=store)
    path, test = corrected(tmp_path)
    quiet(bl.ingest, path, store=store, replace=True, reason="r")
    with sqlite3.connect(store / "manifest.sqlite") as conn:
        conn.execute("UPDATE audit SET sha256 = 'x' WHERE action = 'replace'")
    problems = bl.check_store(store).problems
    assert len(problems) == 1 and repr(test) in problems[0] and "outside backlash" in problems[0]


def test_a_replaced_test_stays_voided_and_the_output_says_so(tmp_path, capsys):
    store = tmp_path / "fleet"
    quiet(bl.ingest, visits(tmp_path, which=("01", "02")), store=store)
    path, test = corrected(tmp_path)
    quiet(bl.void, store, machine="M01", axis="X", test_id=test, reason="wrong setup")
    code, _, err = cli(capsys, ["ingest", "--replace", path, "--store", store, "--reason", "r"])
    assert code == 0 and any(f"test {test!r}" in e and "stays voided" in e for e in err), err
    assert list(open_store(store).voids()["test_id"]) == [test]
    assert test not in set(bl.read(store)["test_id"])


def audit(store) -> list[dict]:
    from pipeline.store import tables

    engine = open_store(store)
    columns = (*tables.AUDIT_COLUMNS, *tables.DIGEST_COLUMNS)
    rows = engine.rows(f"SELECT {', '.join(columns)} FROM {tables.AUDIT[engine.ENGINE]}",
                       tables.AUDIT[engine.ENGINE])
    return [dict(zip(columns, r)) for r in rows]


# --------------------------------------------------------------------- 4. store paths


def test_a_store_in_a_folder_that_does_not_exist_is_refused(tmp_path, capsys):
    path = visits(tmp_path, which=("01",))[0]
    line = refused(capsys, ["ingest", path, "--store", tmp_path / "typo" / "fleet"])
    assert f"the folder {tmp_path / 'typo'} does not exist" in line
    assert not (tmp_path / "typo").exists()


def test_a_new_store_is_announced_once(tmp_path, capsys):
    first, second = visits(tmp_path, which=("01", "02"))
    _, _, err = cli(capsys, ["ingest", first, "--store", tmp_path / "fleet"])
    assert [e for e in err if "new store" in e] == [f"note: new store at {tmp_path / 'fleet'}"]
    _, _, err = cli(capsys, ["ingest", second, "--store", tmp_path / "fleet"])
    assert not [e for e in err if "new store" in e]


def test_an_empty_folder_holds_no_store_yet(tmp_path, capsys):
    (tmp_path / "fleet").mkdir()
    line = refused(capsys, ["iso", tmp_path / "fleet"])
    assert "an empty folder holds no store yet; add tests with backlash ingest" in line
    assert "damaged" not in line


def test_an_interrupted_ingest_says_it_kept_nothing(tmp_path, capsys, monkeypatch):
    from pipeline.store.folder import _FolderTransaction

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(_FolderTransaction, "_write_part", interrupted)
    code, _, err = cli(capsys, ["ingest", *visits(tmp_path, which=("01",)), "--store",
                                tmp_path / "fleet"])
    assert code == 130
    assert err == [(f"backlash ingest: interrupted: nothing was added to the store "
                    f"{tmp_path / 'fleet'} (all files go in one transaction, or none)")]
    checked = bl.check_store(tmp_path / "fleet")
    assert checked.ok and checked.tests == 0  # not damaged: it holds nothing


# --------------------------------------------------------------------- 5. limits


def test_limits_of_a_machine_or_axis_the_store_lacks_are_named(six):
    limits = {"M09": {"X_um": 5.0}, "M01": {"Z_um": 5.0, "X_um": 5.0}}
    notes = notes_of(bl.fleet, six, limits=limits, as_of="2026-09-01")
    assert any("M09.X_um: the data hold no machine M09 (machines M01)" in n for n in notes)
    assert any("M01.Z_um: machine M01 has no axis Z in the data (axes X)" in n for n in notes)
    assert not any("M01.X_um" in n for n in notes)


def test_a_threshold_in_um_on_rotary_axes_only_is_named(tmp_path):
    frame = pd.concat([visit_frame(v) for v in ("01", "02", "03")])
    rotary = bl.validate(frame.assign(axis="C"))
    notes = notes_of(bl.drift, rotary, threshold_um=8.0, as_of="2026-09-01")
    assert any("--threshold-um 8" in n and "rotary axes only (C)" in n for n in notes), notes


# --------------------------------------------------------------------- 6. small things


def test_a_visit_is_found_as_the_store_writes_it(tmp_path, capsys):
    store = tmp_path / "fleet"
    quiet(bl.ingest, visits(tmp_path, which=("01", "02")), store=store)
    code, out, err = cli(capsys, ["void", store, "--machine", "M01", "--axis", "X", "--visit",
                                  "2", "--reason", "laser misaligned", "--json"])
    assert code == 0 and {t["visit"] for t in json.loads(out)["tests"]} == {"02"}
    # one line saying what was done, not the result's repr
    assert len(err) == 1 and not err[0].startswith("VoidResult")
    assert "18 tests of machine M01, axis X voided (visit 02)" in err[0]
    assert "laser misaligned" in err[0]
    line = refused(capsys, ["void", store, "--machine", "M01", "--axis", "X", "--visit", "1",
                            "--reason", "r", "--undo"])
    assert "visit 01 is voided" in line


def test_drift_without_out_or_json_prints_its_table(six, capsys):
    code, out, err = cli(capsys, ["drift", six, "--no-track", "--as-of", "2026-09-01"])
    assert code in (0, 3) and out == ""
    assert err[0].split()[:3] == ["machine", "axis", "unit"]
    assert any(line.startswith("M01") for line in err)


def test_a_python_void_without_a_match_names_the_visit_as_stored(tmp_path):
    store = tmp_path / "fleet"
    quiet(bl.ingest, visits(tmp_path, which=("06",)), store=store)
    with pytest.raises(InputError, match="visit 06, test_id nope"):
        bl.void(store, machine="M01", axis="X", visit="6", test_id="nope", reason="r")
