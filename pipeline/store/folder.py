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
            raise self._error(f"is a folder; expected a readings file or a fleet store (a "
                              f"folder holding {MANIFEST})")
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
        another ingest), held until commit or rollback."""
        if not self.manifest.exists():
            self.create()
        with self._connection(write=True) as conn:
            conn.execute("BEGIN IMMEDIATE")
            tx = _FolderTransaction(self, conn)
            try:
                check_version(conn, self.location)
                tx.sweep()
                yield tx
            finally:
                if not tx.committed:
                    with contextlib.suppress(sqlite3.Error):
                        conn.execute("ROLLBACK")

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
                for table in _record_tables():
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

    # ------------------------------------------------------------------ reading
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
            tables.upgrade(tx.conn, "meta", _record_tables(), "?")
            added = tables.write_rows(tx.conn, tables.TABLES[kind][0], "?", rows)
            if added:
                tx.commit()
        return added

    def get_records(self, kind: str) -> list[tuple]:
        table = tables.TABLES[kind][0]
        with self._connection(write=False) as conn:
            check_version(conn, self.location)
            if conn.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?",
                            (table,)).fetchone() is None:
                return []  # a store of format 1: no records yet
            return conn.execute(f"SELECT {', '.join(tables.COLUMNS)} FROM {table}").fetchall()

    def read_table(self, selection):
        import pyarrow as pa
        import pyarrow.parquet as pq

        from pipeline.store.content import SCHEMA

        where, args = _where(selection)
        with self._connection(write=False) as conn:
            check_version(conn, self.location)
            parts = conn.execute(
                "SELECT part, machine_id, axis FROM parts WHERE part IN "
                f"(SELECT part FROM tests {where}) ORDER BY part", args).fetchall()
        found = []
        for part, machine, axis in parts:
            try:
                table = pq.read_table(self.root / DATA / part)
            except OSError as err:
                raise self._error(f"cannot read part {part} of the store: {err}") from None
            n = table.num_rows
            table = table.append_column("machine_id", pa.array([machine] * n, pa.string()))
            found.append(table.append_column("axis", pa.array([axis] * n, pa.string())))
        if not found:
            return None
        return pa.concat_tables([t.select(SCHEMA.names).cast(SCHEMA) for t in found])


class _FolderTransaction(Transaction):
    """What an ingest does under the manifest's write lock."""

    def __init__(self, store: FolderStore, conn: sqlite3.Connection):
        self.store = store
        self.conn = conn
        self.committed = False

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
        now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        part_of = {}
        for (machine, axis), rows in _partitions(table):
            part = self._write_part(machine, axis, rows)
            part_of[machine, axis] = part
            self.conn.execute("INSERT INTO parts VALUES (?, ?, ?, ?, ?)",
                              (part, machine, axis, rows.num_rows, now))
        self.conn.executemany(
            "INSERT INTO tests VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(*row[:4], row[4], int(row[5]), _iso(row[6]), part_of[row[0], row[1]], now)
             for row in digests[[*KEYS, "sha256", "readings", "started_at"]].itertuples(
                index=False)])

    def _write_part(self, machine: str, axis: str, rows) -> str:
        import pyarrow.parquet as pq

        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        part = (f"machine_id={_segment(machine)}/axis={_segment(axis)}/"
                f"part-{stamp}-{uuid.uuid4().hex[:8]}.parquet")
        with atomic_path(self.store.root / DATA / part) as tmp:
            pq.write_table(rows.drop_columns(["machine_id", "axis"]), tmp)
        return part

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


def _record_tables() -> list[str]:
    return [embedded for embedded, _ in tables.TABLES.values()]


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
    """(machine_id, axis) and the rows of each, for a table sorted by test key."""
    import numpy as np

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
