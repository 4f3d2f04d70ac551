"""The store holds exactly what was ingested, whatever the grouping of files into calls, their
order or the engine; ``backlash store check`` finds what is wrong and ``--repair`` mends only
what is provably safe; ``backlash void`` retires tests from every reader, kept in an audit
table. Both engines (the folder and PostgreSQL on a real server on loopback)."""

from __future__ import annotations

import json
import sqlite3
import uuid
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from store_files import cli, content, refused, visit_frame

import backlash as bl
from pipeline.store import open_store
from pipeline.store.base import MANIFEST

# A small fleet: machine axes and visits, one file each (one feed and dwell per visit: a
# linear and a pendulum test, enough for the fleet view's backlash at every visit).
FILES = [("M1", "X", "01"), ("M1", "Y", "01"), ("M1", "X", "02"), ("M2", "X", "01"),
         ("M1", "Y", "02"), ("M2", "X", "02"), ("M1", "X", "03")]


def small_visit(machine: str, axis: str, visit: str) -> pd.DataFrame:
    frame = visit_frame(visit, machine)
    frame = frame[frame["test_id"].str.contains("-f500-d3-")]
    return frame.assign(axis=axis, test_id=frame["test_id"].str.replace("-X-", f"-{axis}-"))


@pytest.fixture(scope="module")
def fleet_files(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("fleet-files")
    paths = []
    for machine, axis, visit in FILES:
        path = folder / f"{machine}_{axis}_v{visit}.csv"
        small_visit(machine, axis, visit).to_csv(path, index=False)
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def whole(fleet_files) -> pd.DataFrame:
    return content(pd.concat([bl.read(p) for p in fleet_files]))


def new_database(postgres_url: str) -> str:
    from pg_server import create_database

    return create_database(postgres_url, f"integrity_{uuid.uuid4().hex[:10]}")


@pytest.fixture(params=["folder", pytest.param("postgres", marks=pytest.mark.postgres)])
def engine(request):
    """A maker of new empty stores of each engine."""
    if request.param == "folder":
        return lambda folder: str(folder / f"fleet-{uuid.uuid4().hex[:6]}")
    url = request.getfixturevalue("postgres_url")
    return lambda folder: new_database(url)


def test_files_of_interleaved_axes_in_one_call_read_back_whole(engine, tmp_path, fleet_files,
                                                                capsys):
    # X v01, Y v01, X v02: axis X's files are not next to each other in the call
    store = engine(tmp_path)
    code, _, _ = cli(capsys, ["ingest", *fleet_files[:3], "--store", store])
    assert code == 0
    expected = content(pd.concat([bl.read(p) for p in fleet_files[:3]]))
    pd.testing.assert_frame_equal(content(bl.read(store)), expected, check_dtype=False)
    assert bl.check_store(store).ok


def fleet_json(store) -> dict:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = bl.fleet(store, threshold_um=4.0).to_dict()
    assert result.pop("source") == str(store)  # the one place the store's name shows
    return result


@pytest.fixture(scope="module")
def reference(fleet_files, tmp_path_factory) -> dict:
    """``fleet --json`` of the fleet ingested one file per call, in order."""
    store = tmp_path_factory.mktemp("reference") / "fleet"
    for path in fleet_files:
        bl.ingest(path, store=store)
    return fleet_json(store)


@st.composite
def calls(draw):
    """The files in any order, cut into any number of ingest calls."""
    order = draw(st.permutations(range(len(FILES))))
    cuts = draw(st.lists(st.booleans(), min_size=len(FILES) - 1, max_size=len(FILES) - 1))
    groups, current = [], [order[0]]
    for i, cut in zip(order[1:], cuts):
        if cut:
            groups.append(current)
            current = []
        current.append(i)
    return [*groups, current]


@settings(max_examples=8, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(grouping=calls())
def test_any_grouping_and_order_of_files_gives_the_same_store(engine, tmp_path, fleet_files,
                                                              whole, reference, grouping):
    store = engine(tmp_path)
    for group in grouping:
        bl.ingest([fleet_files[i] for i in group], store=store)
    pd.testing.assert_frame_equal(content(bl.read(store)), whole, check_dtype=False)
    assert fleet_json(store) == reference
    assert bl.check_store(store).ok


def test_eighty_files_in_one_call_equal_eight_calls_of_interleaved_files(tmp_path):
    # 10 machine axes x 8 visits, one file each, 4 tests of 80 readings per file
    paths, frames = [], []
    for m in range(5):
        for axis in ("X", "Y"):
            for visit in range(1, 9):
                frame = small_visit(f"M{m}", axis, f"{(visit - 1) % 6 + 1:02d}")
                frame = frame.assign(visit=f"{visit:02d}",
                                     test_id=frame["test_id"] + f"-{visit}")
                path = tmp_path / f"M{m}_{axis}_{visit:02d}.csv"
                frame.to_csv(path, index=False)
                paths.append(path)
                frames.append(frame)
    expected = len(pd.concat(frames))
    one = bl.ingest(paths, store=tmp_path / "one")
    for i in range(8):  # every eighth file, last first: each call interleaves all axes
        bl.ingest(paths[::-1][i::8], store=tmp_path / "each")
    assert one.readings_added == expected == len(bl.read(tmp_path / "one"))
    pd.testing.assert_frame_equal(content(bl.read(tmp_path / "one")),
                                  content(bl.read(tmp_path / "each")))
    assert bl.check_store(tmp_path / "one").ok


# --------------------------------------------------------------------- check and repair


def manifest(store) -> sqlite3.Connection:
    return sqlite3.connect(Path(store) / MANIFEST, isolation_level=None)


def misrecorded(tmp_path, fleet_files) -> Path:
    """A store in the state the grouping bug left: axis X's visit-01 tests name the part of
    visit 02, whose own part no test reads."""
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[0], store=store)
    bl.ingest(fleet_files[2], store=store)
    with manifest(store) as conn:
        first, second = [p for (p,) in conn.execute("SELECT part FROM parts ORDER BY rowid")]
        conn.execute("UPDATE tests SET part = ? WHERE part = ?", (second, first))
    return store


def test_a_test_whose_part_lacks_it_is_an_error_never_a_shorter_table(tmp_path, fleet_files,
                                                                        capsys):
    store = misrecorded(tmp_path, fleet_files)
    line = refused(capsys, ["convert", store, "--out", tmp_path / "out.csv"])
    assert "the store is damaged; run backlash store check" in line
    assert not (tmp_path / "out.csv").exists()


def test_check_finds_misrecorded_tests_and_repair_relinks_them(tmp_path, fleet_files, capsys):
    store = misrecorded(tmp_path, fleet_files)
    code, out, err = cli(capsys, ["store", "check", store])
    assert code == 1
    problems = out.splitlines()
    assert len(problems) == 2  # the two tests of visit 01
    assert all("no reading of it is stored in part" in p and "--repair relinks" in p
               for p in problems)
    assert "2 problems" in err[-1]
    code, out, _ = cli(capsys, ["store", "check", store, "--repair", "--json"])
    result = json.loads(out)
    assert code == 0 and result["ok"] and len(result["repaired"]) == 2
    expected = content(pd.concat([bl.read(fleet_files[0]), bl.read(fleet_files[2])]))
    pd.testing.assert_frame_equal(content(bl.read(store)), expected, check_dtype=False)
    assert cli(capsys, ["store", "check", store])[0] == 0


def test_repair_removes_only_provably_orphaned_files_and_parts(tmp_path, fleet_files, capsys):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[:2], store=store)
    part = next((store / "readings").rglob("part-*.parquet"))
    stray = part.parent / "part-20990101T000000-deadbeef.parquet"
    stray.write_bytes(part.read_bytes())  # as an ingest killed before its commit leaves it
    with manifest(store) as conn:  # a recorded part whose readings are stored elsewhere too
        conn.execute("INSERT INTO parts SELECT 'copy/' || part, machine_id, axis, readings, "
                     "ingested_at FROM parts WHERE part = ?",
                     (part.relative_to(store / "readings").as_posix(),))
    (store / "readings" / "copy").mkdir()
    copy = store / "readings" / "copy" / part.relative_to(store / "readings")
    copy.parent.mkdir(parents=True)
    copy.write_bytes(part.read_bytes())
    checked = bl.check_store(store)
    assert len(checked.problems) == 2
    assert any("is not in the manifest" in p for p in checked.problems)
    assert any("no test reads it" in p for p in checked.problems)
    repaired = bl.check_store(store, repair=True)
    assert repaired.ok and len(repaired.repaired) == 2
    assert not stray.exists() and not copy.exists() and part.exists()
    assert len(bl.read(store)) == sum(len(bl.read(p)) for p in fleet_files[:2])


def test_a_part_holding_tests_the_store_lacks_is_never_removed(tmp_path, fleet_files):
    store = misrecorded(tmp_path, fleet_files)
    with manifest(store) as conn:  # visit 01's tests gone from the manifest
        conn.execute("DELETE FROM tests WHERE visit = '01'")
    checked = bl.check_store(store, repair=True)
    assert any("left as it is" in p for p in checked.problems)
    assert len(list((store / "readings").rglob("*.parquet"))) == 2


def test_a_damaged_part_is_one_line_for_readers_and_a_problem_for_check(tmp_path, fleet_files,
                                                                          capsys):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[0], store=store)
    part = next((store / "readings").rglob("part-*.parquet"))
    part.write_bytes(b"not parquet")
    line = refused(capsys, ["iso", store])
    assert "cannot be read" in line and "run backlash store check" in line
    checked = bl.check_store(store, repair=True)
    assert len(checked.problems) >= 1 and not checked.repaired
    assert part.exists()  # damage is reported, never "repaired" away
    part.unlink()
    assert "is missing" in refused(capsys, ["iso", store])


def test_an_ingest_that_fails_after_writing_parts_leaves_no_file(tmp_path, fleet_files,
                                                                  monkeypatch):
    from pipeline.store import folder

    def fail(self):
        raise RuntimeError("disk full")

    monkeypatch.setattr(folder._FolderTransaction, "commit", fail)
    store = tmp_path / "fleet"
    with pytest.raises(RuntimeError):
        bl.ingest(fleet_files[:3], store=store)
    assert not [p for p in (store / "readings").rglob("*") if p.is_file()]


@pytest.mark.postgres
def test_check_of_a_postgresql_store_compares_every_test(postgres_url, fleet_files):
    import psycopg

    url = new_database(postgres_url)
    bl.ingest(fleet_files[:2], store=url)
    assert bl.check_store(url).ok
    with psycopg.connect(url) as conn:
        conn.execute("DELETE FROM backlash_readings WHERE ctid IN (SELECT ctid FROM "
                     "backlash_readings LIMIT 1)")
    problems = bl.check_store(url).problems
    assert len(problems) == 1 and "readings are stored, the manifest records" in problems[0]


def test_check_of_no_store_is_one_line(tmp_path, capsys):
    assert "no such" in refused(capsys, ["store", "check", tmp_path / "nothing"])


# --------------------------------------------------------------------- void


def test_void_retires_tests_from_every_reader_and_undo_restores_them(engine, tmp_path,
                                                                     fleet_files, capsys):
    store = engine(tmp_path)
    bl.ingest(fleet_files[:3], store=store)
    before = content(bl.read(store))
    code, out, err = cli(capsys, ["void", store, "--machine", "M1", "--axis", "X", "--visit",
                                  "02", "--reason", "laser misaligned", "--json"])
    assert code == 0 and len(json.loads(out)["tests"]) == 2
    assert "2 tests of machine M1, axis X voided" in err[-1]
    after = bl.read(store)
    assert set(after.loc[after["axis"] == "X", "visit"]) == {"01"}
    assert len(after) == len(before) - len(small_visit("M1", "X", "02"))
    voids = open_store(store).voids()
    assert list(voids["reason"]) == ["laser misaligned"] * 2 and voids["user_name"].all()
    assert bl.check_store(store).ok  # a voided test is kept, intact
    bl.void(store, machine="M1", axis="X", visit="02", reason="realigned: valid", undo=True)
    pd.testing.assert_frame_equal(content(bl.read(store)), before)
    assert open_store(store).voids().empty


def test_a_voided_test_ingested_again_stays_voided(tmp_path, fleet_files):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[0], store=store)
    bl.void(store, machine="M1", axis="X", reason="wrong axis")
    with pytest.warns(bl.BacklashWarning, match="nothing changed"):
        bl.ingest(fleet_files[0], store=store)
    with pytest.raises(bl.InputError, match="no test matches"):
        bl.read(store)


@pytest.mark.parametrize(("argv", "words"), [
    (["--machine", "M9", "--axis", "X", "--reason", "r"], "no test matches machine M9"),
    (["--machine", "M1", "--axis", "X", "--test-id", "nope", "--reason", "r"],
     "no test matches"),
    (["--machine", "M1", "--axis", "X", "--reason", "r", "--undo"],
     "M1, axis X is voided; nothing changed"),
    (["--machine", "M1", "--axis", "X", "--reason", "  "], "--reason: expected a value"),
    (["--machine", "M1", "--axis", "X"], "--reason"),
])
def test_a_void_that_cannot_apply_is_one_line_and_changes_nothing(tmp_path, fleet_files,
                                                                   capsys, argv, words):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[0], store=store)
    assert words in refused(capsys, ["void", store, *argv])
    assert open_store(store).voids().empty
    assert len(bl.read(store)) == len(bl.read(fleet_files[0]))


def test_void_of_no_store_writes_nothing(tmp_path, capsys):
    assert "no such store" in refused(capsys, ["void", tmp_path / "none", "--machine", "M1",
                                                "--axis", "X", "--reason", "r"])
    assert not (tmp_path / "none").exists()


def test_a_store_of_the_previous_format_reads_and_is_upgraded_by_its_first_void(tmp_path,
                                                                                fleet_files):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files[0], store=store)
    with manifest(store) as conn:  # as version 2 made it: no void tables
        conn.execute("DROP TABLE voided")
        conn.execute("DROP TABLE audit")
        conn.execute("UPDATE meta SET value = '2' WHERE key = 'format_version'")
    assert len(bl.read(store)) == len(bl.read(fleet_files[0]))
    assert open_store(store).voids().empty
    bl.void(store, machine="M1", axis="X", test_id=bl.read(store)["test_id"].iloc[0],
            reason="r")
    with manifest(store) as conn:
        assert conn.execute("SELECT value FROM meta").fetchone() == ("4",)


@pytest.mark.parametrize(("url", "words"), [
    ("postgresql://[::1/fleet", "Invalid IPv6 URL"),
    ("postgresql://ann:pw@[::1/fleet", "Invalid IPv6 URL"),
    ("postgresql://ann:pw@db:99999/fleet", "Port out of range"),
])
def test_a_malformed_store_url_is_one_line_without_its_password(tmp_path, capsys, url, words):
    for argv in (["iso", url], ["ingest", FILE_OF_ECMC, "--store", url]):
        line = refused(capsys, argv)
        assert "is not a valid URL" in line and words in line and "pw" not in line


FILE_OF_ECMC = str(Path(__file__).resolve().parents[1] / "experiments/data/ecmc/"
                   "ess_mcu1025_ISO230.dat")


def test_the_fleet_view_lists_an_axis_s_voided_tests_and_reads_them_not(tmp_path, fleet_files):
    store = tmp_path / "fleet"
    bl.ingest(fleet_files, store=store)
    bl.void(store, machine="M1", axis="X", visit="03", reason="laser misaligned")
    result = bl.fleet(store, threshold_um=4.0, out=tmp_path / "site")
    axis = next(a for a in result.to_dict()["axes"] if (a["machine_id"], a["axis"]) == ("M1", "X"))
    assert axis["history"]["visits"] == ["01", "02"]
    assert [(t["visit"], t["reason"]) for t in axis["voided_tests"]] == [
        ("03", "laser misaligned")] * 2
    page = (tmp_path / "site" / axis["page"]).read_text(encoding="utf-8")
    assert "Voided tests" in page and "laser misaligned" in page
    others = [a for a in result.to_dict()["axes"] if a["axis"] != "X" or a["machine_id"] != "M1"]
    assert all(a["voided_tests"] == [] for a in others)


def test_an_undated_test_in_a_store_is_left_out_of_the_fleet_view_with_one_note(tmp_path,
                                                                                 fleet_files):
    store = tmp_path / "fleet"
    bl.ingest([*fleet_files, FILE_OF_ECMC], store=store)  # an ecmc test has no start date
    with pytest.warns(bl.BacklashWarning) as caught:
        result = bl.fleet(store, threshold_um=4.0)
    notes = [str(w.message) for w in caught if "no start date" in str(w.message)
             or "undated" in str(w.message) or "without a start" in str(w.message)]
    assert len(notes) == 1 and "ess_mcu1025_ISO230" in notes[0], notes
    assert {(a["machine_id"], a["axis"]) for a in result.to_dict()["axes"]} == {
        ("M1", "X"), ("M1", "Y"), ("M2", "X")}
