"""The fleet store's guarantees on both engines (the embedded folder and PostgreSQL on a real
server started on loopback): a round trip keeps every reading, a SIGKILL mid-ingest leaves the
store as before, concurrent ingests lose nothing, a store of a newer format is refused, a user
without write rights gets one line, and a password never shows."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import tempfile
import uuid
from pathlib import Path

import pandas as pd
import pytest
from store_files import (
    ECMC,
    child_env,
    cli,
    content,
    refused,
    start_stalled,
    twin,
    visit_file,
    visit_frame,
    visits,
)

import backlash as bl
from features.readings.errors import BacklashWarning
from pipeline.cli import main
from pipeline.store.base import FORMAT_VERSION, MANIFEST

PASSWORD = "s3cret-Pw"


def new_database(postgres_url: str) -> str:
    from pg_server import create_database

    return create_database(postgres_url, f"store_{uuid.uuid4().hex[:10]}")


def with_password(url: str) -> str:
    """``url`` with a password (the test server trusts loopback: any password works)."""
    return url.replace("postgres@", f"postgres:{PASSWORD}@", 1)


@pytest.fixture(params=["folder", pytest.param("postgres", marks=pytest.mark.postgres)])
def location(request, tmp_path) -> str:
    """A new store of each engine: a folder name, or a fresh database on the test server."""
    if request.param == "folder":
        return str(tmp_path / "fleet")
    return new_database(request.getfixturevalue("postgres_url"))


def stored(location) -> pd.DataFrame:
    return content(bl.read(location))


def count(location) -> int:
    from pipeline.store import open_store

    return open_store(location).count()


# --------------------------------------------------------------------- round trip


def test_a_round_trip_keeps_every_reading_and_a_second_ingest_changes_nothing(location,
                                                                              tmp_path):
    files = [*visits(tmp_path, which=("01", "02")), ECMC]
    result = bl.ingest(files, store=location)
    assert (result.added, result.tests_in_store) == (37, 37)
    expected = pd.concat([visit_frame("01"), visit_frame("02"), bl.read(ECMC)])
    pd.testing.assert_frame_equal(stored(location), content(expected), check_dtype=False)
    with pytest.warns(BacklashWarning, match="nothing changed"):
        again = bl.ingest(files, store=location)
    assert (again.added, again.unchanged, again.tests_in_store) == (0, 37, 37)


def test_the_two_engines_give_the_same_frame(tmp_path, postgres_url):
    files = visits(tmp_path, which=("01", "03"))
    url = new_database(postgres_url)
    for store in (tmp_path / "fleet", url):
        bl.ingest(files, store=store)
    folder, postgres = bl.read(tmp_path / "fleet"), bl.read(url, since="2026-01-01")
    pd.testing.assert_frame_equal(folder.reset_index(drop=True), postgres.reset_index(drop=True))
    assert list(folder.columns) == list(twin().columns)


def test_a_contradicting_test_is_refused_on_either_engine(location, tmp_path, capsys):
    bl.ingest(visit_file(tmp_path, "01"), store=location)
    frame = visit_frame("01")
    frame.loc[3, "deviation_um"] += 0.2
    path = tmp_path / "other.csv"
    frame.to_csv(path, index=False)
    line = refused(capsys, ["ingest", visit_file(tmp_path, "02"), path, "--store", location])
    assert "already in the store with other readings" in line
    assert count(location) == 18


# --------------------------------------------------------------------- atomic


@pytest.mark.parametrize("where", ["second part", "commit"])
def test_a_sigkill_mid_ingest_leaves_the_store_as_before(location, tmp_path, where):
    if where == "second part" and "://" in location:
        pytest.skip("PostgreSQL writes no parts: one transaction")
    bl.ingest(visit_file(tmp_path, "01"), store=location)
    before = stored(location)
    two = pd.concat([visit_frame("02", "M01"), visit_frame("02", "M02")])
    path = tmp_path / "two_machines.csv"
    two.to_csv(path, index=False)
    child = start_stalled(where, ["ingest", str(path), "--store", location])
    os.kill(child.pid, signal.SIGKILL)
    assert child.wait(60) == -signal.SIGKILL
    assert count(location) == 18
    pd.testing.assert_frame_equal(stored(location), before)
    # the next ingest finds the store as before (and removes what the killed one left)
    assert bl.ingest(path, store=location).added == 36
    assert count(location) == 54
    if "://" not in location:
        import sqlite3

        with sqlite3.connect(f"{location}/{MANIFEST}") as conn:
            parts = {p for (p,) in conn.execute("SELECT part FROM parts")}
        on_disk = {p.relative_to(f"{location}/readings").as_posix()
                   for p in (tmp_path / "fleet" / "readings").rglob("*") if p.is_file()}
        assert on_disk == parts


# --------------------------------------------------------------------- concurrent


def test_four_concurrent_ingests_lose_nothing(location, tmp_path):
    import subprocess

    files = visits(tmp_path)
    batches = [[files[0], files[1]], [files[2], files[0]], [files[3], files[4]], [files[5]]]
    children = [subprocess.Popen([sys.executable, "-m", "pipeline.cli", "ingest",
                                  *map(str, batch), "--store", location, "--json"],
                                 env=child_env(), stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True) for batch in batches]
    outputs = [child.communicate(timeout=600) for child in children]
    assert [child.returncode for child in children] == [0, 0, 0, 0], outputs
    added = [json.loads(out)["added"] for out, _ in outputs]
    assert sum(added) == 6 * 18  # visit 01 twice: stored once
    pd.testing.assert_frame_equal(stored(location), content(twin()), check_dtype=False)


# --------------------------------------------------------------------- newer version


@pytest.mark.postgres
def test_a_postgresql_store_of_a_newer_format_is_refused(postgres_url, tmp_path, capsys):
    import psycopg

    url = new_database(postgres_url)
    bl.ingest(visit_file(tmp_path, "01"), store=url)
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("UPDATE backlash_store SET value = %s WHERE key = 'format_version'",
                     (str(FORMAT_VERSION + 1),))
    for argv in (["ingest", visit_file(tmp_path, "02"), "--store", url], ["drift", url,
                                                                          "--out", tmp_path]):
        line = refused(capsys, argv)
        assert f"store format {FORMAT_VERSION + 1}" in line
    assert count_rows(url) == 18


def count_rows(url: str) -> int:
    import psycopg

    with psycopg.connect(url) as conn:
        return conn.execute("SELECT count(*) FROM backlash_tests").fetchone()[0]


# --------------------------------------------------------------------- access


@pytest.fixture
def shared_folder():
    """A folder every user may look into (pytest's tmp_path is private to root)."""
    folder = tempfile.mkdtemp(prefix="backlash-store-")
    os.chmod(folder, 0o755)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def as_user_without_rights(argv: list[str]) -> tuple[int, str]:
    """``main(argv)`` as a user who owns nothing here: as root (where chmod does not stop
    writes) in a forked child switched to ``nobody``, so the kernel refuses its writes; else in
    this process. Returns the exit code and stderr."""
    if os.geteuid() != 0:
        import contextlib
        import io

        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            return main(argv), err.getvalue()
    import pwd

    nobody = pwd.getpwnam("nobody")
    with tempfile.TemporaryFile(mode="w+") as log:
        pid = os.fork()
        if pid == 0:  # the child: drop root, run, leave without pytest's clean-up
            code = 99
            try:
                sys.stderr = log
                os.setgroups([])
                os.setgid(nobody.pw_gid)
                os.setuid(nobody.pw_uid)
                code = main(argv)
            except BaseException:  # noqa: BLE001 - a traceback is what the test must see
                import traceback

                traceback.print_exc(file=log)
            finally:
                log.flush()
                os._exit(code)
        _, status = os.waitpid(pid, 0)
        log.seek(0)
        return os.waitstatus_to_exitcode(status), log.read()


def lock(folder: str, mode: int) -> None:
    """Without root, take the rights away by mode (root gets them back as ``nobody``)."""
    if os.geteuid() != 0:
        for path in [folder, *map(str, Path(folder).rglob("*"))]:
            os.chmod(path, mode if os.path.isdir(path) else mode & 0o666)


def test_a_user_without_write_rights_gets_one_line_and_may_still_read(shared_folder,
                                                                      capsys):
    store = f"{shared_folder}/fleet"
    first, second = visit_file(shared_folder, "01"), visit_file(shared_folder, "02")
    for path in (first, second):
        os.chmod(path, 0o644)
    assert main(["ingest", str(first), "--store", store]) == 0  # as its owner
    assert main(["iso", store]) == 0
    capsys.readouterr()
    lock(store, 0o555)
    code, err = as_user_without_rights(["ingest", str(second), "--store", store])
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert "cannot write to the store: permission denied" in lines[0]
    assert count(store) == 18
    code, err = as_user_without_rights(["iso", store, "--machine", "M01"])
    assert code == 0, err


def test_an_unreadable_store_folder_is_one_line(shared_folder, capsys):
    store = f"{shared_folder}/fleet"
    assert main(["ingest", str(visit_file(shared_folder, "01")), "--store", store]) == 0
    assert main(["iso", store]) == 0
    capsys.readouterr()
    if os.geteuid() == 0:
        os.chmod(store, 0o700)  # root's own: nobody may not look in
    else:
        lock(store, 0o000)
    try:
        code, err = as_user_without_rights(["iso", store])
    finally:
        lock(store, 0o755)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert "cannot read the store folder: Permission denied" in lines[0]


@pytest.mark.postgres
def test_a_role_without_insert_rights_gets_one_line_and_may_still_read(postgres_url,
                                                                       tmp_path, capsys):
    import psycopg

    url = new_database(postgres_url)
    bl.ingest(visit_file(tmp_path, "01"), store=url)
    role = f"reader_{uuid.uuid4().hex[:8]}"
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f"CREATE ROLE {role} LOGIN")
        conn.execute(f"GRANT SELECT ON ALL TABLES IN SCHEMA public TO {role}")
    reader = url.replace("postgres@", f"{role}:{PASSWORD}@", 1)
    line = refused(capsys, ["ingest", visit_file(tmp_path, "02"), "--store", reader])
    assert "cannot write to the store: permission denied" in line and role in line
    assert PASSWORD not in line
    assert count_rows(url) == 18
    code, _, err = cli(capsys, ["iso", reader, "--json"])
    assert code == 0, err


@pytest.mark.postgres
def test_the_password_never_shows(postgres_url, tmp_path, capsys):
    import mlflow

    url = with_password(new_database(postgres_url))
    outputs = []
    for argv in (["ingest", visit_file(tmp_path, "01"), visit_file(tmp_path, "02"),
                  "--store", url, "--json"],
                 ["ingest", visit_file(tmp_path, "01"), "--store", url],  # a note
                 ["drift", url, "--machine", "M01", "--out", tmp_path / "drift", "--json"],
                 ["iso", url, "--since", "2099-01-01"]):  # an error line
        _, out, err = cli(capsys, argv)
        outputs += [out, *err]
    assert any("note: " in line for line in outputs)
    assert any("error: " in line for line in outputs)
    assert any("postgres:***@" in text for text in outputs)
    result = bl.ingest(visit_file(tmp_path, "03"), store=url)
    outputs += [json.dumps(result.to_dict()), *result.notes, bl.read(url).attrs["source"]]
    runs = mlflow.search_runs(search_all_experiments=True)
    assert len(runs)
    outputs += [str(v) for v in runs.to_numpy().ravel()]
    outputs += [p.read_text(errors="replace") for p in (tmp_path / "drift").rglob("*")
                if p.suffix in (".html", ".json", ".txt", ".csv")]
    leaked = [text for text in outputs if PASSWORD in text]
    assert not leaked, leaked[:3]


@pytest.mark.postgres
def test_an_experiment_step_reads_a_store_url_as_it_is(postgres_url, tmp_path):
    from pipeline import experiment

    url = with_password(new_database(postgres_url))
    bl.ingest(visit_file(tmp_path, "01"), store=url)
    spec = tmp_path / "exp.toml"
    spec.write_text(f'name = "s"\nout = "out"\n[[steps]]\njob = "iso"\n[steps.with]\n'
                    f'data = "{url}"\n')
    loaded = experiment.load(spec)
    assert loaded.steps[0].parameters["data"] == url
    result = experiment.execute(loaded)
    assert PASSWORD not in json.dumps(result.to_dict(), default=str)
