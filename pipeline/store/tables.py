"""The record tables of the fleet store, the same SQL for both engines: one table per kind
of record (``records``), columns ``machine_id``, ``axis``, ``sha256`` (the digest of the
record's canonical text), ``recorded_at`` (ISO 8601, UTC) and ``record`` (the JSON text), keyed
by machine, axis and digest."""

from __future__ import annotations

# Table per kind: (embedded store, PostgreSQL).
TABLES = {"forecast": ("forecasts", "backlash_forecasts"),
          "compensation": ("compensations", "backlash_compensations")}
COLUMNS = ("machine_id", "axis", "sha256", "recorded_at", "record")


def create_sql(table: str) -> str:
    """CREATE of a record table (nothing when it exists: a store upgraded twice is the same)."""
    return (f"CREATE TABLE IF NOT EXISTS {table} (machine_id text NOT NULL, axis text NOT NULL, "
            "sha256 text NOT NULL, recorded_at text NOT NULL, record text NOT NULL, "
            "PRIMARY KEY (machine_id, axis, sha256))")


def insert_sql(table: str, mark: str) -> str:
    """INSERT of one record row; ``mark`` is the engine's parameter mark (``?`` or ``%s``)."""
    return f"INSERT INTO {table} ({', '.join(COLUMNS)}) VALUES ({', '.join([mark] * 5)})"


def upgrade(conn, meta: str, tables, mark: str) -> None:
    """Give a store of an older format the record tables and this format's version (inside
    the caller's transaction: undone with it)."""
    from pipeline.store.base import FORMAT_VERSION

    for table in tables:
        conn.execute(create_sql(table))
    version = conn.execute(f"SELECT value FROM {meta} WHERE key = 'format_version'").fetchone()
    if int(version[0]) < FORMAT_VERSION:
        conn.execute(f"UPDATE {meta} SET value = {mark} WHERE key = 'format_version'",
                     (str(FORMAT_VERSION),))


def write_rows(conn, table: str, mark: str, rows: list[tuple]) -> int:
    """Insert the rows whose digest ``table`` does not hold yet (inside the caller's
    transaction, under the store's write lock); return how many were new."""
    stored = {(m, a, s) for m, a, s in conn.execute(
        f"SELECT machine_id, axis, sha256 FROM {table}").fetchall()}
    new = [r for r in {r[:3]: r for r in rows}.values() if r[:3] not in stored]
    for row in new:
        conn.execute(insert_sql(table, mark), row)
    return len(new)
