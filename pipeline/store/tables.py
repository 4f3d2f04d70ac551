"""The tables every fleet store has beside its readings, the same SQL for both engines.

Record tables (``records``): one per kind of record, columns ``machine_id``, ``axis``,
``sha256`` (the digest of the record's canonical text), ``recorded_at`` (ISO 8601, UTC) and
``record`` (the JSON text), keyed by machine, axis and digest.

Void tables (``voids``): ``voided`` names the tests every reader skips; ``audit`` keeps every
void and undo with when, who and why, never deleted, and every replacement of a test's readings
(``ingest --replace``) with the digest of the readings it replaced (``old_sha256``) and of
those that replaced them (``sha256``; both null for a void or an undo).
"""

from __future__ import annotations

import datetime as dt

# Table per kind: (embedded store, PostgreSQL).
TABLES = {"forecast": ("forecasts", "backlash_forecasts"),
          "compensation": ("compensations", "backlash_compensations"),
          "trace": ("trace_days", "backlash_trace_days"),
          "ballbar": ("ballbar_runs", "backlash_ballbar_runs"),
          "probing": ("probing_runs", "backlash_probing_runs"),
          "stiffness": ("stiffness_runs", "backlash_stiffness_runs")}
COLUMNS = ("machine_id", "axis", "sha256", "recorded_at", "record")
VOIDED = ("voided", "backlash_voided")
AUDIT = ("audit", "backlash_audit")
AUDIT_COLUMNS = ("at", "user_name", "action", "machine_id", "axis", "visit", "test_id",
                 "reason")
# The audit's digests of a replacement (format 4): an audit of format 3 gets them by upgrade.
DIGEST_COLUMNS = ("old_sha256", "sha256")
_KEYS = "machine_id text NOT NULL, axis text NOT NULL, visit text NOT NULL, test_id text NOT NULL"


def now() -> str:
    """The time of recording as fixed-width ISO text in UTC (sorts as it compares)."""
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def create_sql(table: str) -> str:
    """CREATE of a table of this module (nothing when it exists: a store upgraded twice is
    the same)."""
    if table in VOIDED:
        return (f"CREATE TABLE IF NOT EXISTS {table} ({_KEYS}, "
                "PRIMARY KEY (machine_id, axis, visit, test_id))")
    if table in AUDIT:
        return (f"CREATE TABLE IF NOT EXISTS {table} (at text NOT NULL, user_name text NOT NULL, "
                f"action text NOT NULL, {_KEYS}, reason text NOT NULL, old_sha256 text, "
                "sha256 text)")
    return (f"CREATE TABLE IF NOT EXISTS {table} (machine_id text NOT NULL, axis text NOT NULL, "
            "sha256 text NOT NULL, recorded_at text NOT NULL, record text NOT NULL, "
            "PRIMARY KEY (machine_id, axis, sha256))")


def of_engine(engine: int) -> list[str]:
    """Every table of this module for the embedded store (0) or PostgreSQL (1)."""
    return [names[engine] for names in (*TABLES.values(), VOIDED, AUDIT)]


def insert_sql(table: str, mark: str) -> str:
    """INSERT of one record row; ``mark`` is the engine's parameter mark (``?`` or ``%s``)."""
    return f"INSERT INTO {table} ({', '.join(COLUMNS)}) VALUES ({', '.join([mark] * 5)})"


def upgrade(conn, meta: str, tables, mark: str, version: int) -> None:
    """Give a store of an older format the tables of this module and format ``version``
    (inside the caller's transaction: undone with it)."""
    for table in tables:
        conn.execute(create_sql(table))
        if table in AUDIT:
            have = _columns(conn, table, mark)
            for column in DIGEST_COLUMNS:
                if column not in have:
                    conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} text")
    stored = conn.execute(f"SELECT value FROM {meta} WHERE key = 'format_version'").fetchone()
    if int(stored[0]) < version:
        conn.execute(f"UPDATE {meta} SET value = {mark} WHERE key = 'format_version'",
                     (str(version),))


def write_rows(conn, table: str, mark: str, rows: list[tuple]) -> int:
    """Insert the rows whose digest ``table`` does not hold yet (inside the caller's
    transaction, under the store's write lock); return how many were new."""
    stored = {(m, a, s) for m, a, s in conn.execute(
        f"SELECT machine_id, axis, sha256 FROM {table}").fetchall()}
    new = [r for r in {r[:3]: r for r in rows}.values() if r[:3] not in stored]
    for row in new:
        conn.execute(insert_sql(table, mark), row)
    return len(new)


def void_rows(conn, engine: int, mark: str, keys: list[tuple], action: str, at: str,
              user: str, reason: str) -> None:
    """Void (``action="void"``) or restore (``"undo"``) the tests of ``keys`` and add one
    audit row each (inside the caller's transaction, the tables created)."""
    voided, audit = VOIDED[engine], AUDIT[engine]
    where = " AND ".join(f"{k} = {mark}" for k in ("machine_id", "axis", "visit", "test_id"))
    for key in keys:
        if action == "void":
            conn.execute(f"INSERT INTO {voided} VALUES ({', '.join([mark] * 4)})", key)
        else:
            conn.execute(f"DELETE FROM {voided} WHERE {where}", key)
        conn.execute(f"INSERT INTO {audit} ({', '.join(AUDIT_COLUMNS)}) VALUES "
                     f"({', '.join([mark] * len(AUDIT_COLUMNS))})",
                     (at, user, action, *key, reason))


def replace_rows(conn, engine: int, mark: str, replaced, at: str, user: str,
                 reason: str) -> None:
    """One audit row per replaced test (``replaced``: rows of ``KEYS``, ``old_sha256`` and
    ``sha256``), inside the caller's transaction (the tables upgraded)."""
    columns = (*AUDIT_COLUMNS, *DIGEST_COLUMNS)
    sql = (f"INSERT INTO {AUDIT[engine]} ({', '.join(columns)}) VALUES "
           f"({', '.join([mark] * len(columns))})")
    for row in replaced:
        machine, axis, visit, test_id, old, new = row
        conn.execute(sql, (at, user, "replace", machine, axis, visit, test_id, reason, old, new))


def replacements(conn, engine: int, mark: str) -> list[tuple]:
    """Every replacement the audit keeps: (``KEYS``..., ``at``, ``user_name``, ``reason``,
    ``old_sha256``, ``sha256``), oldest first; none in a store that never replaced a test."""
    table = AUDIT[engine]
    if not set(DIGEST_COLUMNS) <= _columns(conn, table, mark):
        return []
    return conn.execute(f"SELECT machine_id, axis, visit, test_id, at, user_name, reason, "
                        f"old_sha256, sha256 FROM {table} WHERE action = 'replace' "
                        "ORDER BY at").fetchall()


def _columns(conn, table: str, mark: str) -> set[str]:
    """The columns of ``table`` (none when it does not exist); ``mark`` tells the engine."""
    if mark == "?":
        return {row[1] for row in conn.execute(f"PRAGMA table_info({table})").fetchall()}
    return {row[0] for row in conn.execute(
        "SELECT column_name FROM information_schema.columns WHERE table_name = %s "
        "AND table_schema = current_schema()", (table,)).fetchall()}
