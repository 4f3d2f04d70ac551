"""The fleet store of a team: five tables in a PostgreSQL database.

``backlash_store`` holds the format version, ``backlash_tests`` one row per test (its key,
digest, number of readings, start) and ``backlash_readings`` every reading in the store's
columns (``content.SCHEMA``). An ingest is one transaction that first takes an advisory lock,
so concurrent ingests run one after the other and each sees what the others committed; the
readings travel by ``COPY`` as CSV both ways. The tables are created by the first ingest;
``backlash_forecasts`` and ``backlash_compensations`` hold the records (``records``).
The password is never part of a message: give it in ``~/.pgpass`` or ``PGPASSWORD``.
"""

from __future__ import annotations

import contextlib
import io

from features.readings.errors import InputError
from pipeline.store import tables
from pipeline.store.base import FORMAT_VERSION, KEYS, Store, Transaction
from pipeline.store.folder import refuse_newer

META, TESTS, READINGS = "backlash_store", "backlash_tests", "backlash_readings"
# pg_advisory_xact_lock key of the store ("backlash" in ASCII).
LOCK = 0x6261636B6C617368
CONNECT_TIMEOUT_S = 10
_TYPES = {"string": "text", "int32": "integer", "int64": "bigint", "double": "double precision"}


class PostgresStore(Store):
    """The store in the PostgreSQL database of ``url`` (see the module docstring).

    Parameters
    ----------
    url : str
        ``postgresql://[user[:password]@]host[:port]/database``.
    location : str
        ``url`` without its password: every message names the store by it.
    write : bool
        Open for ``add``: checks the role may insert (or create the tables).
    parameter : str, optional
        The Python parameter that named the store, for errors.
    """

    def __init__(self, url: str, location: str, password: str | None = None,
                 write: bool = False, parameter: str | None = None):
        self.ENGINE = 1
        self.url = url.replace("postgresql+psycopg://", "postgresql://", 1)
        self.location = location
        self._password = password
        self._parameter = parameter
        with self._connection() as conn:
            exists = self._check_version(conn)
            if write:
                self._check_rights(conn, exists)

    def _error(self, message: str) -> InputError:
        if self._password:
            message = message.replace(self._password, "***")
        return InputError(message, file=self.location, parameter=self._parameter)

    @contextlib.contextmanager
    def _connection(self):
        """A connection (UTC session); a database error becomes one line without password."""
        import psycopg

        try:
            conn = psycopg.connect(self.url, connect_timeout=CONNECT_TIMEOUT_S)
        except psycopg.Error as err:
            raise self._error(f"cannot connect to the store: {_message(err)}") from None
        try:
            with conn:
                conn.execute("SET TIME ZONE 'UTC'")
                yield conn
        except psycopg.errors.InsufficientPrivilege as err:
            raise self._error(f"cannot use the store: permission denied ({_message(err)}); "
                              "ask its owner for the rights") from None
        except psycopg.Error as err:
            raise self._error(f"the store's database refused: {_message(err)}") from None
        finally:
            conn.close()

    def _check_version(self, conn) -> bool:
        """Whether the tables exist; refuses a store of a newer format."""
        if conn.execute("SELECT to_regclass(%s)", (META,)).fetchone()[0] is None:
            return False
        row = conn.execute(f"SELECT value FROM {META} WHERE key = 'format_version'").fetchone()
        refuse_newer(None if row is None else row[0], self.location)
        return True

    def _check_rights(self, conn, exists: bool) -> None:
        if exists:
            allowed = conn.execute("SELECT has_table_privilege(%s, 'INSERT') AND "
                                   "has_table_privilege(%s, 'INSERT')", (TESTS, READINGS))
        else:
            allowed = conn.execute("SELECT has_schema_privilege(current_schema(), 'CREATE')")
        if not allowed.fetchone()[0]:
            user = conn.execute("SELECT current_user").fetchone()[0]
            what = "insert into its tables" if exists else "create its tables"
            raise self._error(f"cannot write to the store: permission denied (role {user!r} "
                              f"may not {what}); ask its owner for the rights")

    # ------------------------------------------------------------------ writing
    @contextlib.contextmanager
    def transaction(self):
        with self._connection() as conn:
            conn.execute("SELECT pg_advisory_xact_lock(%s)", (LOCK,))
            if not self._check_version(conn):
                _create(conn)
            yield _PostgresTransaction(conn)

    # ------------------------------------------------------------------ reading
    def count(self) -> int:
        with self._connection() as conn:
            if not self._check_version(conn):
                return 0
            return conn.execute(f"SELECT count(*) FROM {TESTS}").fetchone()[0]

    def axes(self) -> list[tuple[str, str]]:
        with self._connection() as conn:
            if not self._check_version(conn):
                return []
            return conn.execute(f"SELECT DISTINCT machine_id, axis FROM {TESTS} "
                                "ORDER BY machine_id, axis").fetchall()

    def exists(self) -> bool:
        with self._connection() as conn:
            return self._check_version(conn)

    def put_records(self, kind: str, rows: list[tuple]) -> int:
        with self.transaction() as tx:
            tx.upgrade()
            added = tables.write_rows(tx.conn, tables.TABLES[kind][1], "%s", rows)
            tx.commit()
        return added

    def get_records(self, kind: str) -> list[tuple]:
        table = tables.TABLES[kind][1]
        with self._connection() as conn:
            if not self._check_version(conn) or conn.execute(
                    "SELECT to_regclass(%s)", (table,)).fetchone()[0] is None:
                return []  # no store yet, or one of format 1: no records
            return conn.execute(f"SELECT {', '.join(tables.COLUMNS)} FROM {table}").fetchall()

    def rows(self, query: str, table: str) -> list[tuple]:
        with self._connection() as conn:
            if not self._check_version(conn) or not _has_table(conn, table):
                return []
            return conn.execute(query).fetchall()

    def check(self, repair: bool = False):
        """Every test's readings as the manifest says (count and digest), read in one
        transaction under the store's lock. The database's keys rule out the folder's other
        faults (a reading of an unknown test, a missing part): nothing here to repair."""
        import pandas as pd

        from features.readings.selection import Selection
        from pipeline.store.check import (
            Checked,
            compare,
            found_digests,
            replacement_problems,
        )

        if not self.exists():
            raise self._error("no such store (its tables do not exist)")
        with self.transaction() as tx:
            tests = pd.DataFrame(tx.conn.execute(
                f"SELECT {', '.join(KEYS)}, sha256, readings FROM {TESTS}").fetchall(),
                columns=[*KEYS, "sha256", "readings"])
            table = _copy(tx.conn, Selection(), voids=False)
            replaced = tables.replacements(tx.conn, 1, "%s")
        return Checked(tests=len(tests), readings=int(tests["readings"].sum()),
                       problems=compare(tests, found_digests(table))
                       + replacement_problems(tests, replaced))

    def read_table(self, selection):
        with self._connection() as conn:
            if not self._check_version(conn):
                return None
            return _copy(conn, selection, _has_table(conn, tables.VOIDED[1]))


def _copy(conn, selection, voids: bool):
    """The store table of the readings ``_select`` picks, on ``conn``."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    from pipeline.store.content import SCHEMA

    buffer = io.BytesIO()
    with conn.cursor().copy(_select(selection, voids)) as copy:
        for block in copy:
            buffer.write(block)
    if not buffer.getbuffer().nbytes:
        return pa.Table.from_pylist([], schema=SCHEMA)
    buffer.seek(0)
    return pcsv.read_csv(buffer, read_options=pcsv.ReadOptions(column_names=SCHEMA.names),
                         convert_options=pcsv.ConvertOptions(
                             column_types=dict(zip(SCHEMA.names, SCHEMA.types)),
                             strings_can_be_null=False))


class _PostgresTransaction(Transaction):
    """What an ingest does inside its transaction (the advisory lock held)."""

    ENGINE, MARK, META, TESTS = 1, "%s", META, TESTS

    def __init__(self, conn):
        self.conn = conn

    def has_table(self, name: str) -> bool:
        return _has_table(self.conn, name)

    def stored(self, digests):
        import pandas as pd

        rows = self.conn.execute(
            f"SELECT {', '.join(KEYS)}, sha256 FROM {TESTS} WHERE machine_id = ANY(%s)",
            (sorted(set(digests["machine_id"])),)).fetchall()
        return pd.DataFrame(rows, columns=[*KEYS, "sha256"])

    def write(self, table, digests) -> None:
        import pyarrow.csv as pcsv

        columns = [*KEYS, "sha256", "readings", "started_at"]
        with self.conn.cursor().copy(f"COPY {TESTS} ({', '.join(columns)}) FROM STDIN") as copy:
            for row in digests[columns].itertuples(index=False):
                copy.write_row([*row[:5], int(row[5]),
                                None if row[6] is None or row[6] != row[6] else row[6]])
        buffer = io.BytesIO()
        pcsv.write_csv(table, buffer, pcsv.WriteOptions(include_header=False))
        with self.conn.cursor().copy(f"COPY {READINGS} ({', '.join(table.column_names)}) "
                                     "FROM STDIN (FORMAT csv)") as copy:
            copy.write(buffer.getbuffer())

    def replace(self, table, digests) -> None:
        """The stored readings of the tests of ``digests`` deleted and these written (the
        keys tie every reading to its test, so only one set can be held; the audit keeps the
        digest of the replaced one)."""
        keys = [tuple(k) for k in digests[KEYS].itertuples(index=False)]
        where = " AND ".join(f"{k} = %s" for k in KEYS)
        for key in keys:
            self.conn.execute(f"DELETE FROM {READINGS} WHERE {where}", key)
            self.conn.execute(f"DELETE FROM {TESTS} WHERE {where}", key)
        self.write(table, digests)

    def commit(self) -> None:
        self.conn.commit()


def _create(conn) -> None:
    """The store's tables, in the ingest's transaction."""
    from pipeline.store.content import OPTIONAL, SCHEMA

    columns = ", ".join(
        f"{f.name} {'timestamptz' if str(f.type).startswith('timestamp') else _TYPES[str(f.type)]}"
        f"{'' if f.name in OPTIONAL else ' NOT NULL'}" for f in SCHEMA)
    keys = ", ".join(KEYS)
    conn.execute(f"CREATE TABLE {META} (key text PRIMARY KEY, value text NOT NULL)")
    conn.execute(f"INSERT INTO {META} VALUES ('format_version', %s)", (str(FORMAT_VERSION),))
    conn.execute(f"CREATE TABLE {TESTS} (machine_id text NOT NULL, axis text NOT NULL, "
                 "visit text NOT NULL, test_id text NOT NULL, sha256 text NOT NULL, "
                 "readings integer NOT NULL, started_at timestamptz, "
                 f"ingested_at timestamptz NOT NULL DEFAULT now(), PRIMARY KEY ({keys}))")
    conn.execute(f"CREATE TABLE {READINGS} ({columns}, PRIMARY KEY ({keys}, seq), "
                 f"FOREIGN KEY ({keys}) REFERENCES {TESTS})")
    for table in tables.of_engine(1):
        conn.execute(tables.create_sql(table))


def _select(selection, voids: bool = False):
    """``COPY (SELECT ...) TO STDOUT``: the readings of the tests ``selection`` may keep and
    no voided test (``voids``: the store has the void table), times as ISO text in UTC
    (undated tests stay in: ``Selection.apply`` notes them)."""
    from psycopg import sql

    from pipeline.store.content import SCHEMA

    iso = 'YYYY-MM-DD"T"HH24:MI:SS.US"Z"'
    columns = sql.SQL(", ").join(
        sql.SQL("to_char({c} AT TIME ZONE 'UTC', {f})").format(c=sql.Identifier(f.name),
                                                             f=sql.Literal(iso))
        if str(f.type).startswith("timestamp") else sql.Identifier(f.name) for f in SCHEMA)
    clauses = []
    for name, column in (("machine", "machine_id"), ("axis", "axis")):
        values = getattr(selection, name)
        if values is not None:
            clauses.append(sql.SQL("{} = ANY({})").format(sql.Identifier(column),
                                                          sql.Literal(list(values))))
    times = [sql.SQL("started_at {} {}").format(sql.SQL(op), sql.Literal(t.to_pydatetime()))
             for op, t in ((">=", selection.since), ("<=", selection.until)) if t is not None]
    if times:
        clauses.append(sql.SQL("(started_at IS NULL OR ({}))").format(
            sql.SQL(" AND ").join(times)))
    keys = sql.SQL(", ").join(map(sql.Identifier, KEYS))
    conditions = []
    if clauses:
        conditions.append(sql.SQL("({}) IN (SELECT {} FROM {} WHERE {})").format(
            keys, keys, sql.Identifier(TESTS), sql.SQL(" AND ").join(clauses)))
    if voids:
        conditions.append(sql.SQL("({}) NOT IN (SELECT {} FROM {})").format(
            keys, keys, sql.Identifier(tables.VOIDED[1])))
    where = sql.SQL("")
    if conditions:
        where = sql.SQL(" WHERE ") + sql.SQL(" AND ").join(conditions)
    return sql.SQL("COPY (SELECT {} FROM {}{}) TO STDOUT (FORMAT csv)").format(
        columns, sql.Identifier(READINGS), where)


def _has_table(conn, name: str) -> bool:
    return conn.execute("SELECT to_regclass(%s)", (name,)).fetchone()[0] is not None


def _message(err) -> str:
    """A database error as one short line (libpq's hints and contexts left out)."""
    text = str(err).strip() or type(err).__name__
    return " ".join(text.split())
