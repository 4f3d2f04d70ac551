"""``backlash ingest`` / ``bl.ingest`` into the embedded store, and every command reading a
store (or a file) with the test filters: every accepted layout goes in through the readers of
every other job, the same test twice changes nothing, a test stored with other readings is
refused, bad input is one line with exit 2 and nothing written."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import warnings

import pandas as pd
import pytest
from store_files import (
    ECMC,
    cli,
    content,
    layout_files,
    refused,
    twin,
    visit_file,
    visit_frame,
    visits,
)

import backlash as bl
from features.readings.errors import BacklashWarning, InputError
from features.readings.io import read_readings
from pipeline.cli import build_parser
from pipeline.store.base import FORMAT_VERSION, MANIFEST


def snapshot(folder) -> dict:
    """Every file below ``folder`` with the digest of its bytes."""
    if not folder.exists():
        return {}
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def store(tmp_path):
    """A store holding visits 01-03 of M01."""
    location = tmp_path / "fleet"
    bl.ingest(visits(tmp_path, which=("01", "02", "03")), store=location)
    return location


# --------------------------------------------------------------------- what goes in


def test_every_accepted_layout_is_ingested_as_its_reader_reads_it(tmp_path, capsys):
    files = layout_files(tmp_path)
    code, out, err = cli(capsys, ["ingest", *files.values(), "--store", tmp_path / "s",
                                  "--json"])
    assert code == 0, err
    result = json.loads(out)
    assert [f["added"] for f in result["files"]] == [f["tests"] for f in result["files"]]
    stored = bl.read(tmp_path / "s")
    for path in files.values():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BacklashWarning)
            given = read_readings(path)
        keys = given[["machine_id", "axis", "visit", "test_id"]].drop_duplicates()
        back = stored.merge(keys)[given.columns]
        pd.testing.assert_frame_equal(content(back), content(given), check_dtype=False)
    assert result["tests_in_store"] == sum(f["tests"] for f in result["files"])


def test_the_same_tests_again_change_nothing_and_say_so(store, tmp_path, capsys):
    before = snapshot(store)
    (tmp_path / "again").mkdir()
    again = visit_file(tmp_path / "again", "02")
    code, out, err = cli(capsys, ["ingest", again, "--store", store, "--json"])
    assert code == 0
    assert json.loads(out)["added"] == 0 and json.loads(out)["unchanged"] == 18
    assert any(line.startswith("note: ") and "already in the store" in line for line in err)
    assert any("nothing changed" in line for line in err)
    assert snapshot(store) == before


def test_the_same_readings_in_another_order_and_layout_are_the_same_test(store, tmp_path):
    shuffled = visit_frame("03").sample(frac=1, random_state=3)
    path = tmp_path / "shuffled.parquet"
    shuffled.to_parquet(path)
    with pytest.warns(BacklashWarning, match="already in the store"):
        result = bl.ingest(path, store=store)
    assert (result.added, result.unchanged) == (0, 18)


def test_new_tests_are_added_beside_the_stored_ones(store, tmp_path):
    result = bl.ingest([visit_file(tmp_path, "03"), visit_file(tmp_path, "04")], store=store)
    assert (result.added, result.unchanged, result.tests_in_store) == (18, 18, 72)
    assert result.readings_added == 1440
    assert result.to_dict()["files"][1] == {"file": str(tmp_path / "M01_v04.csv"),
                                            "readings": 1440, "tests": 18, "added": 18,
                                            "replaced": 0, "unchanged": 0}


def test_a_test_stored_with_other_readings_is_refused_and_nothing_changes(store, tmp_path,
                                                                         capsys):
    changed = visit_frame("04")
    changed.loc[0, "deviation_um"] += 0.5
    other = tmp_path / "changed_v03.csv"
    frame = visit_frame("03")
    frame.loc[5, "deviation_um"] += 0.1
    frame.to_csv(other, index=False)
    new = tmp_path / "v04.csv"
    changed.to_csv(new, index=False)
    before = snapshot(store)
    line = refused(capsys, ["ingest", new, other, "--store", store])
    assert str(other) in line and "already in the store with other readings" in line
    assert repr(frame["test_id"].iloc[5]) in line
    assert snapshot(store) == before


def test_two_files_that_disagree_on_a_test_are_refused_before_any_write(tmp_path, capsys):
    first = visit_file(tmp_path, "01")
    frame = visit_frame("01")
    frame.loc[0, "deviation_um"] -= 1.0
    second = tmp_path / "second.csv"
    frame.to_csv(second, index=False)
    line = refused(capsys, ["ingest", first, second, "--store", tmp_path / "s"])
    assert str(second) in line and f"also in {first}" in line
    assert not (tmp_path / "s").exists()


def test_a_test_given_twice_in_one_ingest_is_stored_once(tmp_path):
    path = visit_file(tmp_path, "01")
    with pytest.warns(BacklashWarning, match="18 of 18 tests already in the store"):
        result = bl.ingest([path, path], store=tmp_path / "s")
    assert (result.added, result.unchanged, result.tests_in_store) == (18, 18, 18)


def test_extra_columns_are_refused_or_left_out_with_a_note(tmp_path):
    path = tmp_path / "extra.csv"
    visit_frame("01").assign(operator="ann").to_csv(path, index=False)
    with pytest.raises(InputError, match="unknown column operator; the store keeps only"):
        bl.ingest(path, store=tmp_path / "s")
    with pytest.warns(BacklashWarning, match="column operator left out of the store"):
        bl.ingest(path, store=tmp_path / "s", allow_unknown_columns=True)
    assert "operator" not in bl.read(tmp_path / "s").columns


def test_hostile_machine_ids_go_in_and_come_back(tmp_path):
    names = ["A/B #<'\"> ü", "..", "%2F", "x" * 300, "y" * 299 + "ü"]
    frames = [visit_frame("01", name) for name in names]
    path = tmp_path / "hostile.parquet"
    pd.concat(frames).to_parquet(path)
    bl.ingest(path, store=tmp_path / "s")
    back = bl.read(tmp_path / "s")
    assert sorted(back["machine_id"].unique()) == sorted(names)
    assert set(bl.read(tmp_path / "s", machine="..")["machine_id"]) == {".."}
    folders = [p.name for p in (tmp_path / "s" / "readings").iterdir()]
    assert len(folders) == len(names) and all(len(f.encode()) <= 211 for f in folders)


# --------------------------------------------------------------------- bad input


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    good = visit_file(tmp_path, "01")
    wrong = tmp_path / "notes.csv"
    wrong.write_text("who,what\nann,oiled the screw\n")
    a_file = tmp_path / "store.txt"
    a_file.write_text("keep me")
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "axis.jpg").write_bytes(b"\xff\xd8")
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / MANIFEST).write_bytes(b"this is not a database" * 100)
    cases = {
        "file": ([good, "--store", a_file], "is a file; expected a store folder"),
        "foreign folder": ([good, "--store", foreign], "not a fleet store"),
        "unreadable manifest": ([good, "--store", corrupt], "cannot read the store's manifest"),
        "other engine": ([good, "--store", "mysql://ann:pw@db/fleet"], "mysql:// URL"),
        "wrong layout": ([wrong, "--store", tmp_path / "new"], "unknown format"),
        "missing file": ([tmp_path / "nope.csv", "--store", tmp_path / "new"], "no such file"),
    }
    for name, (argv, words) in cases.items():
        before = snapshot(tmp_path)
        line = refused(capsys, ["ingest", *argv])
        assert words in line, (name, line)
        assert "pw" not in line
        assert snapshot(tmp_path) == before, name


def test_a_store_written_by_a_newer_version_is_refused(store, tmp_path, capsys):
    with sqlite3.connect(store / MANIFEST) as conn:
        conn.execute("UPDATE meta SET value = ? WHERE key = 'format_version'",
                     (str(FORMAT_VERSION + 1),))
    before = snapshot(store)
    for argv in (["ingest", visit_file(tmp_path, "04"), "--store", store], ["iso", store]):
        line = refused(capsys, argv)
        assert f"store format {FORMAT_VERSION + 1}" in line and "upgrade" in line
    assert snapshot(store) == before


def test_an_unreachable_postgresql_url_is_one_line_without_its_password(tmp_path, capsys):
    url = "postgresql://ann:top-secret@127.0.0.1:9/fleet"
    for argv in (["ingest", visit_file(tmp_path, "01"), "--store", url], ["iso", url]):
        line = refused(capsys, argv)
        assert "cannot connect to the store" in line and "ann:***@" in line
        assert "top-secret" not in line


# --------------------------------------------------------------------- every command reads it


def test_every_command_that_reads_data_takes_a_store_and_the_filters():
    parser = build_parser()
    readers = [name for name, command in parser.commands.items()
               if any("--format" in a.option_strings for a in command._actions)]
    assert set(readers) >= {"convert", "iso", "train", "predict", "compare", "tune", "rank",
                            "replicate", "drift", "discover", "compensate", "ingest"}
    for name in set(readers) - {"ingest"}:
        options = {o for a in parser.commands[name]._actions for o in a.option_strings}
        assert {"--machine", "--axis", "--since", "--until"} <= options, name
        positional = next(a for a in parser.commands[name]._actions if not a.option_strings
                          and a.dest != "model")
        assert "fleet store" in positional.help, name


def test_iso_of_a_store_selection_is_iso_of_the_same_tests_read_from_files(store, tmp_path,
                                                                          capsys):
    code, from_store, _ = cli(capsys, ["iso", store, "--machine", "M01", "--axis", "x",
                                       "--since", "2026-01-01", "--json"])
    assert code == 0
    frame = twin()
    frame = frame[frame["visit"].isin(["01", "02", "03"])]
    path = tmp_path / "three.csv"
    frame.to_csv(path, index=False)
    code, from_file, _ = cli(capsys, ["iso", path, "--json"])
    key = [*("machine_id", "axis", "visit", "test_id")]
    assert sorted(json.loads(from_store), key=lambda t: [t[k] for k in key]) == sorted(
        json.loads(from_file), key=lambda t: [t[k] for k in key])


def test_since_and_until_select_whole_days_of_started_at(store, capsys):
    starts = twin().groupby("visit")["started_at"].min()
    day = starts["02"].strftime("%Y-%m-%d")
    selected = bl.read(store, since=day, until=day)
    assert set(selected["visit"]) == {"02"}
    assert selected.attrs["source"] == f"{store} (since {day}; until {day})"
    later = bl.read(store, since=starts["02"].isoformat())
    assert set(later["visit"]) == {"02", "03"}
    code, _, err = cli(capsys, ["convert", store, "--until", day, "--out",
                                store.parent / "early.parquet"])
    assert code == 0, err
    assert set(pd.read_parquet(store.parent / "early.parquet")["visit"]) == {"01", "02"}


def test_the_filters_apply_to_a_file_too(tmp_path, capsys):
    two = pd.concat([visit_frame("01", "M01"), visit_frame("01", "M02")])
    path = tmp_path / "two.csv"
    two.to_csv(path, index=False)
    code, out, _ = cli(capsys, ["iso", path, "--machine", "M02", "--json"])
    assert code == 0 and {t["machine_id"] for t in json.loads(out)} == {"M02"}
    assert set(bl.read(path, machine=["M02"])["machine_id"]) == {"M02"}


def test_a_model_command_trains_on_a_store_selection(store, tmp_path, capsys):
    bl.ingest(visit_file(tmp_path, "01", "M02"), store=store)
    code, _, err = cli(capsys, ["train", store, "--machine", "M01", "--model", "ridge",
                                "--out", tmp_path / "model"])
    assert code == 0, err
    import mlflow

    run = mlflow.search_runs(experiment_names=["train"]).iloc[0]
    assert run["params.data"] == f"{store} (machine M01)"


@pytest.mark.parametrize("argv, words", [
    (["--since", "2026-13-01"], "--since: '2026-13-01' is not an ISO 8601 date"),
    (["--axis", "Q"], "--axis: unknown axis 'Q'"),
    (["--machine", " , "], "--machine: is empty"),
    (["--since", "2026-06-01", "--until", "2026-01-01"], "--since: since 2026-06-01 is after"),
    (["--machine", "M09"], "no test matches machine M09; the store holds machines M01"),
    (["--format", "ecmc"], "--format: is 'ecmc', but a fleet store holds validated readings"),
])
def test_a_filter_that_cannot_select_is_one_line(store, capsys, argv, words):
    assert words in refused(capsys, ["iso", store, *argv])


def test_a_date_filter_leaves_undated_tests_out_with_a_note(tmp_path):
    bl.ingest([visit_file(tmp_path, "06"), ECMC], store=tmp_path / "s")
    with pytest.warns(BacklashWarning, match="1 tests without started_at left out by since"):
        frame = bl.read(tmp_path / "s", since="2026-01-01")
    assert set(frame["machine_id"]) == {"M01"}


def test_a_date_filter_on_a_file_without_dates_is_one_line(capsys):
    assert "no started_at column" in refused(capsys, ["iso", ECMC, "--since", "2026-01-01"])


def test_a_folder_that_is_no_store_is_one_line_as_data(tmp_path, capsys):
    line = refused(capsys, ["iso", tmp_path])
    assert "is a folder; expected a readings file or a fleet store" in line


def test_an_empty_store_is_one_line(tmp_path, capsys):
    (tmp_path / "s").mkdir()
    from pipeline.store.folder import FolderStore

    FolderStore(tmp_path / "s", write=True).create()
    assert "holds no test yet" in refused(capsys, ["iso", tmp_path / "s"])


def test_compensate_reads_a_store_and_keeps_axis_for_a_model(store, tmp_path, capsys):
    code, _, err = cli(capsys, ["compensate", store, "--axis", "X", "--machine", "M01",
                                "--controller", "csv", "--out", tmp_path / "comp"])
    assert code == 0, err
    model = tmp_path / "model"
    model.mkdir()
    line = refused(capsys, ["compensate", model, "--since", "2026-01-01", "--controller",
                            "csv", "--out", tmp_path / "comp2"])
    assert "--since: selects tests of readings" in line


# --------------------------------------------------------------------- Python


def test_python_reads_a_store_with_the_same_filters(store):
    frame = bl.read(str(store), machine="M01", axis=["X"], until="2026-12-31")
    assert set(frame["visit"]) == {"01", "02", "03"}
    assert bl.iso(frame).figures["test_id"].nunique() == 54
    assert len(bl.iso(store).figures) == 54  # a store path works wherever a file does
    with pytest.raises(InputError) as err:
        bl.read(store, since="yesterday")
    assert err.value.parameter == "since"


def test_ingest_checks_its_parameters(tmp_path):
    with pytest.raises(InputError) as err:
        bl.ingest([], store=tmp_path / "s")
    assert err.value.parameter == "files"
    with pytest.raises(InputError) as err:
        bl.ingest(visit_file(tmp_path, "01"), store=3)
    assert err.value.parameter == "store"


def test_the_store_page_lists_every_filter_as_its_record_says():
    from store_files import REPO

    from features.readings.selection import FILTERS

    text = (REPO / "docs" / "store.md").read_text(encoding="utf-8")
    missing = [f.name for f in FILTERS if f"| `--{f.name} {f.metavar}` | {f.help} |" not in text]
    assert not missing, missing
