"""What every fleet store does, whatever its engine: add tests in one transaction (new ones
written, identical ones left alone, contradicting ones refused) and read a selection back.

An engine (``folder``, ``postgres``) supplies a ``Transaction``: the digests already stored
for some tests, a write of new tests, a commit. ``Store.add`` holds the rules, so both
engines refuse and accept exactly the same tests.
"""

from __future__ import annotations

from dataclasses import dataclass

from features.readings import schema
from features.readings.errors import InputError
from pipeline.store import tables

# The version of the store's layout this code writes and reads. A store written by a newer
# version (a larger number in its manifest or table) is refused, never guessed at. Version 2
# added the record tables (``records``): a version-1 store reads as having no records and is
# upgraded by its first record. Version 3 added the void tables (``tables.VOIDED``, ``AUDIT``):
# a reader of version 2 would read a voided test, so a store with voids must refuse it.
# Version 4 added the audit's digests of a replaced test (``tables.DIGEST_COLUMNS``): the
# readings a replacement superseded stay in their part, which the check of version 3 would
# take for an orphan and its repair remove.
FORMAT_VERSION = 4
# The embedded store's manifest: a folder holding it is a store.
MANIFEST = "manifest.sqlite"
KEYS = list(schema.TEST_KEYS)


@dataclass
class Added:
    """What one ``Store.add`` did.

    Attributes
    ----------
    new : DataFrame
        Digest rows (``content.digests``) of the tests written.
    same : DataFrame
        Digest rows of the tests that were already stored with the same readings.
    replaced : DataFrame or None
        With ``replace``: digest rows of the tests whose readings were replaced, with the
        digest they had (``old_sha256``).
    voided : tuple
        The keys of the replaced tests that are voided (they stay voided).
    """

    new: object
    same: object
    replaced: object = None
    voided: tuple = ()


class Transaction:
    """What an engine does inside its write transaction (``Store.transaction()``, a context
    manager holding the store's write lock, rolls back whatever was not committed).

    ``conn`` is the engine's DB-API connection; ``ENGINE`` (0 embedded, 1 PostgreSQL),
    ``MARK`` (its parameter mark), ``META`` and ``TESTS`` (its table names) let the SQL that
    both engines share be written once."""

    ENGINE: int
    MARK: str
    META: str
    TESTS: str
    conn: object

    def has_table(self, name: str) -> bool:
        raise NotImplementedError

    def upgrade(self) -> None:
        """Give a store of an older format every table of ``tables`` and this version."""
        tables.upgrade(self.conn, self.META, tables.of_engine(self.ENGINE), self.MARK,
                       FORMAT_VERSION)

    def matching(self, machine: str, axis: str, visit=None, test_id=None,
                 voided: bool = False) -> list[tuple]:
        """Keys of the stored tests of ``machine`` and ``axis`` (and ``visit``, ``test_id``
        when given) that are voided (``voided``) or not, sorted."""
        given = {"machine_id": machine, "axis": axis, "visit": visit, "test_id": test_id}
        given = {k: v for k, v in given.items() if v is not None}
        where = " AND ".join(f"t.{k} = {self.MARK}" for k in given)
        table = tables.VOIDED[self.ENGINE]
        if self.has_table(table):
            where += (f" AND {'' if voided else 'NOT '}EXISTS (SELECT 1 FROM {table} AS v WHERE "
                      + " AND ".join(f"v.{k} = t.{k}" for k in KEYS) + ")")
        elif voided:
            return []
        return sorted(self.conn.execute(f"SELECT {', '.join(KEYS)} FROM {self.TESTS} AS t "
                                        f"WHERE {where}", tuple(given.values())).fetchall())

    def visit_as_stored(self, machine: str, axis: str, visit):
        """``visit`` as the store writes it for the machine axis: ``8`` is the stored ``08``
        (the same number, where exactly one stored visit has it), so a visit typed without
        its leading zero finds its tests and a refusal names the visit as stored."""
        if visit is None:
            return None
        stored = [v for (v,) in self.conn.execute(
            f"SELECT DISTINCT visit FROM {self.TESTS} WHERE machine_id = {self.MARK} AND "
            f"axis = {self.MARK}", (machine, axis)).fetchall()]
        if visit in stored or not visit.strip().isdigit():
            return visit
        same = [v for v in stored if v.strip().isdigit() and int(v) == int(visit)]
        return same[0] if len(same) == 1 else visit

    def stored(self, digests):
        """Digest rows (``KEYS`` + ``sha256``) of the tests of ``digests`` already stored."""
        raise NotImplementedError

    def write(self, table, digests) -> None:
        """Write the readings (``content`` store table, Arrow) and digests of new tests."""
        raise NotImplementedError

    def replace(self, table, digests) -> None:
        """Write the readings and digests of stored tests in place of those stored (every
        reader reads the new ones; the audit row is the caller's)."""
        raise NotImplementedError

    def voided_of(self, keys: list[tuple]) -> list[tuple]:
        """The keys among ``keys`` that are voided."""
        table = tables.VOIDED[self.ENGINE]
        if not keys or not self.has_table(table):
            return []
        found = set(self.conn.execute(f"SELECT {', '.join(KEYS)} FROM {table}").fetchall())
        return [k for k in keys if tuple(k) in found]

    def commit(self) -> None:
        raise NotImplementedError


class Store:
    """A fleet store. ``location`` names it in every message, without a password."""

    location: str

    def transaction(self):
        """A context manager: the store's write lock held, a ``Transaction`` inside."""
        raise NotImplementedError

    def read_table(self, selection):
        """The store table (Arrow) of the tests ``selection`` may keep, or None when empty."""
        raise NotImplementedError

    def count(self) -> int:
        """Tests in the store."""
        raise NotImplementedError

    def axes(self) -> list[tuple[str, str]]:
        """(machine_id, axis) of every machine axis in the store, sorted."""
        raise NotImplementedError

    def exists(self) -> bool:
        """Whether the store has been made (by its first ingest)."""
        raise NotImplementedError

    def put_records(self, kind: str, rows: list[tuple]) -> int:
        """Add record rows of ``kind`` (``records.rows_of``) in one transaction under the
        store's write lock, upgrading a store of an older format; return how many were new
        (a row whose digest is stored already is left as it is)."""
        raise NotImplementedError

    def get_records(self, kind: str) -> list[tuple]:
        """Every stored row of ``kind`` (``records.COLUMNS``); none in an older store."""
        raise NotImplementedError

    def rows(self, query: str, table: str) -> list[tuple]:
        """The rows of a read-only ``query`` that reads ``table`` (none when the store or the
        table does not exist yet)."""
        raise NotImplementedError

    def check(self, repair: bool = False):
        """Verify the store (``check.Checked``); ``repair`` removes what is provably orphaned."""
        raise NotImplementedError

    def void(self, machine: str, axis: str, visit=None, test_id=None, *, reason: str,
             undo: bool = False) -> list[tuple]:
        """Retire the matching tests (``undo``: restore them) and keep who, when and why.

        Returns
        -------
        list of tuple
            The keys (``KEYS``) of the tests voided or restored.

        Raises
        ------
        InputError
            No stored test matches (none voided, with ``undo``); nothing is written.
        """
        with self.transaction() as tx:
            visit = tx.visit_as_stored(machine, axis, visit)
            keys = tx.matching(machine, axis, visit, test_id, voided=undo)
            if not keys:
                what = ", ".join(f"{k} {v}" for k, v in (("machine", machine), ("axis", axis),
                                 ("visit", visit), ("test_id", test_id)) if v is not None)
                if not tx.matching(machine, axis, visit, test_id, voided=not undo):
                    raise InputError(f"no test matches {what}", file=self.location)
                state = "voided" if undo else "not voided"
                raise InputError(f"no test that matches {what} is {state}; nothing changed",
                                 file=self.location)
            tx.upgrade()
            tables.void_rows(tx.conn, tx.ENGINE, tx.MARK, keys, "undo" if undo else "void",
                             tables.now(), _user(), reason)
            tx.commit()
        return keys

    def voids(self):
        """The voided tests (``KEYS``) with the ``at``, ``user_name`` and ``reason`` of their
        void, sorted by key (an empty frame when there are none)."""
        import pandas as pd

        engine = self.ENGINE
        audit = self.rows(f"SELECT {', '.join(tables.AUDIT_COLUMNS)} FROM "
                          f"{tables.AUDIT[engine]} WHERE action = 'void' ORDER BY at",
                          tables.AUDIT[engine])
        voided = self.rows(f"SELECT {', '.join(KEYS)} FROM {tables.VOIDED[engine]}",
                           tables.VOIDED[engine])
        audit = pd.DataFrame(audit, columns=list(tables.AUDIT_COLUMNS))
        last = audit.drop_duplicates(KEYS, keep="last")
        frame = pd.DataFrame(voided, columns=KEYS).merge(last, on=KEYS, how="left")
        return frame[[*KEYS, "at", "user_name", "reason"]].sort_values(KEYS, ignore_index=True)

    def add(self, table, digests, replace: bool = False, reason: str | None = None) -> Added:
        """Add tests in one transaction, or with ``replace`` put corrected readings in place
        of stored ones.

        Parameters
        ----------
        table : pyarrow.Table
            Readings in the store's form (``content.store_table``).
        digests : DataFrame
            One row per test of ``table``: ``KEYS``, ``sha256``, ``readings``, ``started_at``
            and ``file`` (where it came from, for messages).
        replace : bool
            Every test must be stored already; those stored with other readings get these
            readings, and the audit a row each with the time, the user, ``reason`` and both
            digests. A voided test stays voided.
        reason : str, optional
            Why the tests are replaced (``replace`` only).

        Raises
        ------
        InputError
            A test is already stored with other readings (``replace``: a test not stored),
            naming its file and the test; nothing is written.
        """
        with self.transaction() as tx:
            stored = tx.stored(digests)
            if replace:
                return self._replace(tx, table, digests, stored, reason)
            same = _check_same(digests, stored)
            new = digests[~same].reset_index(drop=True)
            if len(new):
                tx.write(_rows_of(table, digests, same), new)
                tx.commit()
        return Added(new, digests[same].reset_index(drop=True))

    def _replace(self, tx, table, digests, stored, reason) -> Added:
        both = digests.merge(stored, on=KEYS, how="left", suffixes=("", "_stored"))
        unknown = both["sha256_stored"].isna().to_numpy()
        if unknown.any():
            row = both[unknown].iloc[0]
            raise InputError(f"test {row['test_id']!r} (machine {row['machine_id']}, axis "
                             f"{row['axis']}, visit {row['visit']}) is not in the store; "
                             "--replace replaces stored tests only (ingest new tests without "
                             "it); nothing was changed", file=row["file"])
        same = (both["sha256_stored"] == both["sha256"]).to_numpy()
        changed = both[~same].rename(columns={"sha256_stored": "old_sha256"})
        changed = changed.reset_index(drop=True)
        voided = ()
        if len(changed):
            tx.upgrade()  # the audit's digest columns
            tx.replace(_rows_of(table, digests, same), digests[~same].reset_index(drop=True))
            tables.replace_rows(tx.conn, tx.ENGINE, tx.MARK,
                                changed[[*KEYS, "old_sha256", "sha256"]].itertuples(index=False),
                                tables.now(), _user(), reason or "")
            voided = tuple(tx.voided_of(list(changed[KEYS].itertuples(index=False, name=None))))
            tx.commit()
        return Added(digests[:0], digests[same].reset_index(drop=True), changed, voided)

    def read(self, selection):
        """The validated readings frame of the tests ``selection`` keeps.

        Raises
        ------
        InputError
            The store holds no test yet, or none that ``selection`` keeps.
        """
        from pipeline.store.content import readings_frame

        table = self.read_table(selection)
        if table is None or table.num_rows == 0:
            axes = self.axes()
            if not axes:
                raise InputError("the store holds no test yet; add some with backlash ingest",
                                 file=self.location)
            machines = sorted({m for m, _ in axes})
            shown = ", ".join(machines[:5]) + (" ..." if len(machines) > 5 else "")
            raise InputError(f"no test matches {selection.text}; the store holds machines "
                             f"{shown} and axes {', '.join(sorted({a for _, a in axes}))}",
                             file=self.location)
        return selection.apply(readings_frame(table, self.location), self.location)


def _user() -> str:
    """The operating-system user, for the audit table (a uid where no name is known, as in
    some containers)."""
    import getpass
    import os

    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return f"uid {os.getuid()}"


def _check_same(digests, stored):
    """Boolean mask of ``digests`` rows already stored with the same readings; refuses a
    test stored with other readings."""
    import numpy as np

    if len(stored) == 0:
        return np.zeros(len(digests), dtype=bool)
    both = digests.merge(stored, on=KEYS, how="left", suffixes=("", "_stored"))
    known = both["sha256_stored"].notna().to_numpy()
    other = known & (both["sha256_stored"] != both["sha256"]).to_numpy()
    if other.any():
        row = both[other].iloc[0]
        raise InputError(f"test {row['test_id']!r} (machine {row['machine_id']}, axis "
                         f"{row['axis']}, visit {row['visit']}) is already in the store with "
                         "other readings; nothing was added (ingest it under a new test_id or "
                         "visit)", file=row["file"])
    return known


def _rows_of(table, digests, same):
    """The rows of ``table`` that belong to the tests not marked ``same``."""
    if not same.any():
        return table
    import pyarrow as pa
    import pyarrow.compute as pc

    old = digests.loc[same, KEYS]
    key = pc.binary_join_element_wise(*[table[k] for k in KEYS], "\x1f")
    old_keys = pa.array(["\x1f".join(k) for k in old.itertuples(index=False)], pa.string())
    return table.filter(pc.invert(pc.is_in(key, value_set=old_keys)))
