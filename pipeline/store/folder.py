"""The embedded fleet store: a folder holding a Parquet dataset and a SQLite manifest.

```
STORE/
  manifest.sqlite                 format version, one row per committed part and per test
  readings/machine_id=M01/axis=X/part-20260131T101500-3f2a9c1e.parquet
```

The dataset under ``readings/`` is Hive-partitioned by machine and axis (partition values
percent-encoded), so pyarrow, DuckDB, Dask and Spark read it as it is. The manifest is the
truth: a part counts once its row is committed. The manifest also holds the forecasts and
compensations recorded for the store's axes (``records``). An ingest takes the manifest's write lock
(``BEGIN IMMEDIATE``: concurrent ingests wait for each other), writes its parts under
hidden temporary names, renames them into place, records parts and tests, and commits. A
process killed before the commit leaves a rolled-back manifest and, at worst, parts no
manifest row names: every reader ignores them and the next ingest removes them.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import sqlite3
import stat
import time
import uuid
from pathlib import Path
from urllib.parse import quote

from features.readings.errors import InputError
from features.readings.fileio import TEMP_MARK, atomic_path
from pipeline.store import tables
from pipeline.store.base import FORMAT_VERSION, KEYS, MANIFEST, Store, Transaction

DATA = "readings"
# Seconds an ingest waits for another one's write lock before giving up.
BUSY_S = 600.0
# Longest partition folder name [bytes] before it is shortened (file systems allow 255).
MAX_SEGMENT = 200
_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE parts (part TEXT PRIMARY KEY, machine_id TEXT NOT NULL, axis TEXT NOT NULL,
                    readings INTEGER NOT NULL, ingested_at TEXT NOT NULL);
CREATE TABLE tests (machine_id TEXT NOT NULL, axis TEXT NOT NULL, visit TEXT NOT NULL,
                    test_id TEXT NOT NULL, sha256 TEXT NOT NULL, readings INTEGER NOT NULL,
                    started_at TEXT, part TEXT NOT NULL REFERENCES parts (part),
                    ingested_at TEXT NOT NULL,
                    PRIMARY KEY (machine_id, axis, visit, test_id));
"""


class FolderStore(Store):
    """The embedded store in folder ``root`` (see the module docstring).

    Parameters
    ----------
    root : path-like
        The store folder; for writing, a folder that does not exist yet or is empty is a new
        store.
    write : bool
        Open for ``add`` (checks write permission) rather than for reading.
    parameter : str, optional
        The Python parameter that named the store, for errors.
    """

    def __init__(self, root, write: bool = False, parameter: str | None = None):
        self.ENGINE = 0
        self.root = Path(root)
        self.location = str(root)
        self.manifest = self.root / MANIFEST
        self._parameter = parameter
        exists = self._check_folder(write)
        if exists:
            with self._connection(write=False) as conn:
                check_version(conn, self.location)
        if write:
            self._check_writable(exists)

    # ------------------------------------------------------------------ opening
    def _error(self, message: str) -> InputError:
        return InputError(message, file=self.location, parameter=self._parameter)

    def _check_folder(self, write: bool) -> bool:
        """Whether the store exists; refuses a file, an unreadable folder, a foreign folder."""
        try:
            mode = self.root.stat().st_mode
        except FileNotFoundError:
            parent = self.root.absolute().parent
            if write and not parent.is_dir():  # a mistyped path, never a tree of new folders
                raise self._error(f"the folder {parent} does not exist; a new store is made "
                                  "only inside an existing folder") from None
            if write:
                return False
            raise self._error("no such file or store folder") from None
        except OSError as err:
            raise self._error(f"cannot open the store: {err.strerror}") from None
        if not stat.S_ISDIR(mode):
            raise self._error("is a file; expected a store folder or a postgresql:// URL")
        try:
            if self.manifest.is_file():
                return True
            entries = [e for e in os.listdir(self.root) if not e.startswith(".")]
        except OSError as err:
            raise self._error(f"cannot read the store folder: {err.strerror}") from None
        if not write:
            # an empty folder is what a first ingest interrupted before its manifest leaves:
            # no store yet, not a damaged one
            empty = (": an empty folder holds no store yet; add tests with backlash ingest"
                     if not entries else "")
            raise self._error(f"is a folder; expected a readings file or a fleet store (a "
                              f"folder holding {MANIFEST}){empty}")
        if entries:
            raise self._error(f"is a folder but not a fleet store (no {MANIFEST}); expected a "
                              "store, an empty folder or a new name")
        return False

    def _check_writable(self, exists: bool) -> None:
        place = self.root if exists else _existing_parent(self.root)
        paths = [place, self.manifest] if exists else [place]
        if not all(os.access(p, os.W_OK) for p in paths):
            raise self._error(f"cannot write to the store: permission denied ({place}); ask "
                              "its owner for write rights")

    @contextlib.contextmanager
    def _connection(self, write: bool):
        """A connection to the manifest (read-write where the file allows it: a reader may
        have to roll back the journal of a killed ingest); sqlite errors become one line."""
        rw = write or os.access(self.manifest, os.W_OK)
        uri = f"file:{quote(str(self.manifest.absolute()))}?mode={'rw' if rw else 'ro'}"
        conn = None
        try:
            conn = sqlite3.connect(uri, uri=True, timeout=BUSY_S, isolation_level=None)
            yield conn
        except sqlite3.Error as err:
            raise self._error(_sqlite_message(err)) from None
        finally:
            if conn is not None:
                conn.close()

    # ------------------------------------------------------------------ writing
    @contextlib.contextmanager
    def transaction(self):
        """The manifest's write lock (``BEGIN IMMEDIATE``: waits up to ``BUSY_S`` for
        another ingest), held until commit or rollback; parts no manifest row names are
        swept first."""
        with self._locked() as tx:
            tx.sweep()
            yield tx

    @contextlib.contextmanager
    def _locked(self):
        if not self.manifest.exists():
            self.create()
        with self._connection(write=True) as conn:
            conn.execute("BEGIN IMMEDIATE")
            tx = _FolderTransaction(self, conn)
            try:
                check_version(conn, self.location)
                yield tx
            finally:
                if not tx.committed:
                    with contextlib.suppress(sqlite3.Error):
                        conn.execute("ROLLBACK")
                    tx.remove_written()  # no part outlives an ingest that did not commit

    def create(self) -> None:
        """Create the manifest of a new store (two processes creating it at once both end
        with the one manifest the first one linked into place)."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise self._error(f"cannot create the store folder: {err.strerror}") from None
        tmp = self.root / f".{MANIFEST}.{uuid.uuid4().hex[:8]}{TEMP_MARK}{os.getpid()}"
        try:
            with contextlib.closing(sqlite3.connect(tmp, isolation_level=None)) as conn:
                conn.executescript(_SCHEMA)
                for table in tables.of_engine(0):
                    conn.execute(tables.create_sql(table))
                conn.execute("INSERT INTO meta VALUES ('format_version', ?)",
                             (str(FORMAT_VERSION),))
            with contextlib.suppress(FileExistsError):
                os.link(tmp, self.manifest)
        except (OSError, sqlite3.Error) as err:
            raise self._error(f"cannot create the store: {_reason(err)}") from None
        finally:
            with contextlib.suppress(OSError):
                tmp.unlink()

    # ------------------------------------------------------------------ checking
    def check(self, repair: bool = False):
        """Verify every part and test against the manifest (see ``check``). Under the write
        lock (so an ingest under way is never taken for damage) where the manifest may be
        written; ``repair`` relinks a test to the recorded part that holds its readings
        intact, and removes files the manifest does not name and recorded parts that no test
        reads and that hold nothing the store lacks."""
        if not self.exists():
            raise self._error("no such store (no manifest)")
        if not repair and not os.access(self.manifest, os.W_OK):
            with self._connection(write=False) as conn:
                return _FolderCheck(self, conn, repair=False).run()
        with self._locked() as tx:
            checked = _FolderCheck(self, tx.conn, repair).run()
            if checked.repaired:
                tx.commit()
            return checked

    # ------------------------------------------------------------------ reading
    def rows(self, query: str, table: str) -> list[tuple]:
        if not self.exists():
            return []
        with self._connection(write=False) as conn:
            return conn.execute(query).fetchall() if _has_table(conn, table) else []

    def count(self) -> int:
        with self._connection(write=False) as conn:
            return conn.execute("SELECT count(*) FROM tests").fetchone()[0]

    def axes(self) -> list[tuple[str, str]]:
        with self._connection(write=False) as conn:
            return conn.execute("SELECT DISTINCT machine_id, axis FROM tests "
                                "ORDER BY machine_id, axis").fetchall()

    def exists(self) -> bool:
        return self.manifest.is_file()

    def put_records(self, kind: str, rows: list[tuple]) -> int:
        with self.transaction() as tx:
            tx.upgrade()
            added = tables.write_rows(tx.conn, tables.TABLES[kind][0], "?", rows)
            if added:
                tx.commit()
        return added

    def get_records(self, kind: str) -> list[tuple]:
        table = tables.TABLES[kind][0]
        with self._connection(write=False) as conn:
            check_version(conn, self.location)
            if not _has_table(conn, table):
                return []  # a store of format 1: no records yet
            return conn.execute(f"SELECT {', '.join(tables.COLUMNS)} FROM {table}").fetchall()

    def read_table(self, selection):
        import pyarrow as pa

        from pipeline.store.content import SCHEMA

        where, args = _where(selection)
        with self._connection(write=False) as conn:
            check_version(conn, self.location)
            if _has_table(conn, tables.VOIDED[0]):
                where += (" AND" if where else "WHERE") + _NOT_VOIDED
            rows = conn.execute(f"SELECT part, machine_id, axis, visit, test_id, readings "
                                f"FROM tests AS t {where} ORDER BY part", args).fetchall()
        found = [self._tests_in_part(part, list(tests))
                 for part, tests in itertools.groupby(rows, key=lambda r: r[0])]
        if not found:
            return None
        return pa.concat_tables([t.select(SCHEMA.names).cast(SCHEMA) for t in found])

    def _tests_in_part(self, part: str, tests: list[tuple]):
        """The rows of ``tests`` (manifest rows: part, machine, axis, visit, test_id, count)
        in their part; a part that cannot be read or lacks some of their readings is an
        error, never a silently shorter table."""
        import pyarrow as pa
        import pyarrow.compute as pc

        table = self._read_part(part)
        key = pc.binary_join_element_wise(table["visit"], table["test_id"], "\x1f")
        wanted = pa.array([f"{t[3]}\x1f{t[4]}" for t in tests], pa.string())
        table = table.filter(pc.is_in(key, value_set=wanted))
        expected = sum(t[5] for t in tests)
        if table.num_rows != expected:
            raise self._error(f"part {part} holds {table.num_rows} readings of its "
                              f"{len(tests)} tests, the manifest {expected}: the store is "
                              "damaged; run backlash store check")
        return _with_partition(table, tests[0][1], tests[0][2])

    def _read_part(self, part: str):
        """One part file as Arrow; a missing or damaged file is one line."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        path = self.root / DATA / part
        if not path.is_file():
            raise self._error(f"part {part} is missing from the store folder; run backlash "
                              "store check")
        try:
            return pq.read_table(path)
        except (OSError, pa.ArrowException) as err:
            raise self._error(f"part {part} cannot be read ({_first_line(err)}): the store is "
                              "damaged; run backlash store check") from None


class _FolderTransaction(Transaction):
    """What an ingest does under the manifest's write lock."""

    ENGINE, MARK, META, TESTS = 0, "?", "meta", "tests"

    def __init__(self, store: FolderStore, conn: sqlite3.Connection):
        self.store = store
        self.conn = conn
        self.committed = False
        self.written: list[Path] = []

    def has_table(self, name: str) -> bool:
        return _has_table(self.conn, name)

    def stored(self, digests):
        import pandas as pd

        machines = sorted(set(digests["machine_id"]))
        rows = []
        for i in range(0, len(machines), 500):  # SQLite's limit of bound parameters
            chunk = machines[i:i + 500]
            rows += self.conn.execute(
                f"SELECT {', '.join(KEYS)}, sha256 FROM tests WHERE machine_id IN "
                f"({', '.join('?' * len(chunk))})", chunk).fetchall()
        return pd.DataFrame(rows, columns=[*KEYS, "sha256"])

    def write(self, table, digests) -> None:
        now, part_of = self._write_parts(table)
        self.conn.executemany(
            "INSERT INTO tests VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(*row[:4], row[4], int(row[5]), _iso(row[6]), part_of[row[0], row[1]], now)
             for row in digests[[*KEYS, "sha256", "readings", "started_at"]].itertuples(
                index=False)])

    def replace(self, table, digests) -> None:
        """New parts hold the corrected readings and the tests are read from them; the parts
        that held the replaced readings are never rewritten (the readings other tests read
        from them stay, and the replaced ones stay as the history the audit's digests name)."""
        now, part_of = self._write_parts(table)
        self.conn.executemany(
            "UPDATE tests SET sha256 = ?, readings = ?, started_at = ?, part = ?, "
            "ingested_at = ? WHERE machine_id = ? AND axis = ? AND visit = ? AND test_id = ?",
            [(row[4], int(row[5]), _iso(row[6]), part_of[row[0], row[1]], now, *row[:4])
             for row in digests[[*KEYS, "sha256", "readings", "started_at"]].itertuples(
                index=False)])

    def _write_parts(self, table) -> tuple[str, dict]:
        """One part per machine axis of ``table``, recorded; the time and each one's part."""
        now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        part_of = {}
        for (machine, axis), rows in _partitions(table):
            part = self._write_part(machine, axis, rows)
            part_of[machine, axis] = part
            self.conn.execute("INSERT INTO parts VALUES (?, ?, ?, ?, ?)",
                              (part, machine, axis, rows.num_rows, now))
        return now, part_of

    def _write_part(self, machine: str, axis: str, rows) -> str:
        import pyarrow.parquet as pq

        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        part = (f"machine_id={_segment(machine)}/axis={_segment(axis)}/"
                f"part-{stamp}-{uuid.uuid4().hex[:8]}.parquet")
        path = self.store.root / DATA / part
        with atomic_path(path) as tmp:
            pq.write_table(rows.drop_columns(["machine_id", "axis"]), tmp)
        self.written.append(path)
        return part

    def remove_written(self) -> None:
        for path in self.written:
            with contextlib.suppress(OSError):
                path.unlink()

    def commit(self) -> None:
        self.conn.execute("COMMIT")
        self.committed = True

    def sweep(self) -> None:
        """Remove parts no manifest row names: left by an ingest killed before its commit
        (under the write lock no other ingest is between its rename and its commit)."""
        folder = self.store.root / DATA
        if not folder.is_dir():
            return
        known = {p for (p,) in self.conn.execute("SELECT part FROM parts")}
        for path in folder.glob("*/*/part-*.parquet"):
            if path.relative_to(folder).as_posix() not in known:
                with contextlib.suppress(OSError):
                    path.unlink()


def check_version(conn, location: str) -> None:
    """Refuse a store whose format version is newer than this code's."""
    try:
        row = conn.execute("SELECT value FROM meta WHERE key = 'format_version'").fetchone()
    except sqlite3.DatabaseError as err:
        raise InputError(f"cannot read the store's manifest: {err}", file=location) from None
    refuse_newer(None if row is None else row[0], location)


def refuse_newer(version, location: str) -> None:
    """One line for a store without a version or written by a newer version."""
    if version is None or not str(version).isdigit():
        raise InputError(f"the store has no valid format version ({version!r}); expected "
                         f"{FORMAT_VERSION}", file=location)
    if int(version) > FORMAT_VERSION:
        raise InputError(f"the store was written by a newer backlash (store format "
                         f"{version}; this version reads up to {FORMAT_VERSION}); upgrade "
                         "backlash-pipeline", file=location)


def _where(selection) -> tuple[str, list]:
    """The manifest's WHERE clause for ``selection`` (exactness comes later: the same
    ``Selection.apply`` as for a file)."""
    clauses, args = [], []
    for name, column in (("machine", "machine_id"), ("axis", "axis")):
        values = getattr(selection, name)
        if values is not None:
            clauses.append(f"{column} IN ({', '.join('?' * len(values))})")
            args += list(values)
    times = [(op, _iso(t)) for op, t in ((">=", selection.since), ("<=", selection.until))
             if t is not None]
    if times:  # undated tests stay in: Selection.apply leaves them out with a note
        clauses.append("(started_at IS NULL OR ("
                       + " AND ".join(f"started_at {op} ?" for op, _ in times) + "))")
        args += [t for _, t in times]
    return ("WHERE " + " AND ".join(clauses) if clauses else ""), args


def _partitions(table):
    """(machine_id, axis) and all the rows of each, whatever the order of ``table``'s rows.

    An ingest concatenates its files in the order given, so one machine axis may come in
    several runs (X, Y, X); each machine axis must still become exactly one part, or the
    tests of all but one of its runs would name a part that does not hold them. Arrow's sort
    is stable: the rows of each test keep their order."""
    import numpy as np

    table = table.sort_by([("machine_id", "ascending"), ("axis", "ascending")])
    machine = table["machine_id"].to_numpy(zero_copy_only=False)
    axis = table["axis"].to_numpy(zero_copy_only=False)
    cut = np.flatnonzero(np.r_[True, (machine[1:] != machine[:-1]) | (axis[1:] != axis[:-1])])
    for lo, hi in zip(cut, np.r_[cut[1:], len(machine)]):
        yield (str(machine[lo]), str(axis[lo])), table.slice(lo, hi - lo)


def _segment(value: str) -> str:
    """A partition value as a folder name: percent-encoded (Hive style); beyond
    ``MAX_SEGMENT`` bytes a prefix and a hash of the whole (the manifest keeps the value)."""
    text = quote(value, safe="")
    if len(text) <= MAX_SEGMENT:
        return text
    head = text[:MAX_SEGMENT - 13]
    cut = head.rfind("%", len(head) - 2)  # never half an escape
    digest = hashlib.sha256(value.encode("utf-8")).hexdigest()[:12]
    return f"{head if cut < 0 else head[:cut]}~{digest}"


def _iso(stamp) -> str | None:
    """A UTC time as fixed-width ISO text (sorts as it compares); None for NaT."""
    import pandas as pd

    if stamp is None or pd.isna(stamp):
        return None
    return pd.Timestamp(stamp).tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%S.%fZ")


class _FolderCheck:
    """One check of a folder store on ``conn`` (see ``FolderStore.check``)."""

    def __init__(self, store: FolderStore, conn, repair: bool):
        import pandas as pd

        self.store, self.conn, self.repair = store, conn, repair
        # part -> (machine_id, axis, readings) as the manifest records it
        self.parts = {p: (m, a, n) for p, m, a, n in conn.execute(
            "SELECT part, machine_id, axis, readings FROM parts").fetchall()}
        self.tests = pd.DataFrame(conn.execute(
            f"SELECT {', '.join(KEYS)}, sha256, readings, part FROM tests").fetchall(),
            columns=[*KEYS, "sha256", "readings", "part"])
        from pipeline.store.check import Checked, superseded

        self.out = Checked(tests=len(self.tests), readings=int(self.tests["readings"].sum()))
        self.replacements = tables.replacements(conn, 0, "?")
        self.superseded = superseded(self.replacements)

    def run(self):
        from pipeline.store.check import replacement_problems

        held = self._read_parts()
        self._unrecorded_files()
        self._tests(held)
        self._unread_parts(held)
        self.out.problems += replacement_problems(self.tests, self.replacements)
        return self.out

    def _problem(self, text: str, mend=None) -> None:
        """``text`` as a problem, or as repaired once ``mend()`` has run (``repair`` only)."""
        if self.repair and mend is not None:
            mend()
            self.out.repaired.append(text)
        else:
            self.out.problems.append(text)

    def _read_parts(self) -> dict:
        """Part -> digest rows of the tests it holds (parts that cannot be read: problems)."""
        from pipeline.store.check import found_digests

        held = {}
        for part, (machine, axis, readings) in self.parts.items():
            try:
                table = self.store._read_part(part)
            except InputError as err:
                self._problem(err.message)
                continue
            if table.num_rows != readings:
                self._problem(f"part {part} holds {table.num_rows} readings, the manifest "
                              f"records {readings}")
            held[part] = found_digests(_with_partition(table, machine, axis))
        return held

    def _unrecorded_files(self) -> None:
        folder = self.store.root / DATA
        if not folder.is_dir():
            return
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            part = path.relative_to(folder).as_posix()
            if part not in self.parts:
                self._problem(f"file {DATA}/{part} is not in the manifest (left by an "
                              "interrupted ingest): nothing reads it", path.unlink)

    def _tests(self, held: dict) -> None:
        """Each test's readings intact in its part; else relinked to a part holding them."""
        from pipeline.store.check import mismatch, name

        where = {}  # test key -> [(part, digest row)]
        for part, found in held.items():
            for row in found.itertuples(index=False):
                where.setdefault(tuple(getattr(row, k) for k in KEYS), []).append((part, row))
        for i, test in enumerate(self.tests.itertuples(index=False)):
            places = dict(where.get(tuple(getattr(test, k) for k in KEYS), []))
            if test.part not in self.parts:
                why = f"its part {test.part} is not recorded"
            elif test.part not in held:
                continue  # the part's own problem is listed
            else:
                why = mismatch(test, places.get(test.part))
            if why is None:
                continue
            intact = [p for p, row in places.items() if mismatch(test, row) is None]
            text = f"{name(test)}: {why} in part {test.part}"
            if not intact:
                self._problem(text)
                continue
            self.tests.loc[i, "part"] = intact[0]  # where it is read from once relinked
            self._problem(f"{text}; part {intact[0]} holds them intact"
                          + ("" if self.repair else ": --repair relinks the test to it"),
                          lambda test=test, part=intact[0]: self._relink(test, part))

    def _relink(self, test, part: str) -> None:
        self.conn.execute("UPDATE tests SET part = ? WHERE machine_id = ? AND axis = ? AND "
                          "visit = ? AND test_id = ?", (part, *(getattr(test, k) for k in KEYS)))

    def _unread_parts(self, held: dict) -> None:
        """Recorded parts no test reads: removed when every test they hold is intact in
        the part it is read from (nothing the store lacks)."""
        tests = self.tests.set_index(KEYS)
        for part in sorted(set(self.parts) - set(self.tests["part"])):
            found = held.get(part)
            if found is None:
                continue
            rows = list(found.itertuples(index=False))
            history = [k for k in rows
                       if (*(getattr(k, c) for c in KEYS), k.sha256) in self.superseded]
            own = [k for k in rows if k not in history
                   and not _intact_elsewhere(tests, tuple(getattr(k, c) for c in KEYS), held)]
            if history and not own:
                continue  # the readings replacements superseded: the audit's history, kept
            if own:
                self._problem(f"part {part} is recorded but no test reads it, and it holds "
                              f"{len(own)} tests the store has nowhere else: left as it is")
                continue
            self._problem(f"part {part} is recorded but no test reads it (every reading in it "
                          "is stored elsewhere)", lambda part=part: self._drop_part(part))

    def _drop_part(self, part: str) -> None:
        self.conn.execute("DELETE FROM parts WHERE part = ?", (part,))
        with contextlib.suppress(FileNotFoundError):
            (self.store.root / DATA / part).unlink()


def _with_partition(table, machine: str, axis: str):
    """A part's table with its partition values (kept in the folder names, not the file) as
    the ``machine_id`` and ``axis`` columns."""
    import pyarrow as pa

    n = table.num_rows
    table = table.append_column("machine_id", pa.array([machine] * n, pa.string()))
    return table.append_column("axis", pa.array([axis] * n, pa.string()))


def _intact_elsewhere(tests, key: tuple, held: dict) -> bool:
    """Whether the test ``key`` is in the manifest and intact in the part it is read from."""
    from pipeline.store.check import mismatch

    if key not in tests.index:
        return False
    test = tests.loc[key]
    found = held.get(test["part"])
    if found is None:
        return False
    row = found[(found[KEYS] == list(key)).all(axis=1)]
    return len(row) == 1 and mismatch(test, next(row.itertuples(index=False))) is None


_NOT_VOIDED = (" NOT EXISTS (SELECT 1 FROM voided AS v WHERE v.machine_id = t.machine_id AND "
               "v.axis = t.axis AND v.visit = t.visit AND v.test_id = t.test_id)")


def _has_table(conn, name: str) -> bool:
    return conn.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?",
                        (name,)).fetchone() is not None


def _first_line(err: Exception) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def _existing_parent(path: Path) -> Path:
    path = path.absolute()
    while not path.exists():
        path = path.parent
    return path


def _sqlite_message(err: sqlite3.Error) -> str:
    name = getattr(err, "sqlite_errorname", "")
    if name.startswith("SQLITE_READONLY") or name == "SQLITE_PERM":
        return ("cannot write to the store: permission denied (an interrupted ingest may need "
                "a user with write rights to roll it back)")
    if name == "SQLITE_BUSY":
        return f"the store stayed locked by another ingest for {BUSY_S:.0f} s; try again"
    return f"cannot use the store's manifest: {err}"


def _reason(err: Exception) -> str:
    return err.strerror if isinstance(err, OSError) and err.strerror else str(err)
