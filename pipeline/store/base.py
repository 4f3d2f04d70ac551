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

# The version of the store's layout this code writes and reads. A store written by a newer
# version (a larger number in its manifest or table) is refused, never guessed at. Version 2
# added the record tables (``records``): a version-1 store reads as having no records and is
# upgraded by its first record.
FORMAT_VERSION = 2
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
    """

    new: object
    same: object


class Transaction:
    """What an engine does inside its write transaction (``Store.transaction()``, a context
    manager holding the store's write lock, rolls back whatever was not committed)."""

    def stored(self, digests):
        """Digest rows (``KEYS`` + ``sha256``) of the tests of ``digests`` already stored."""
        raise NotImplementedError

    def write(self, table, digests) -> None:
        """Write the readings (``content`` store table, Arrow) and digests of new tests."""
        raise NotImplementedError

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

    def add(self, table, digests) -> Added:
        """Add tests in one transaction.

        Parameters
        ----------
        table : pyarrow.Table
            Readings in the store's form (``content.store_table``).
        digests : DataFrame
            One row per test of ``table``: ``KEYS``, ``sha256``, ``readings``, ``started_at``
            and ``file`` (where it came from, for messages).

        Raises
        ------
        InputError
            A test is already stored with other readings (naming its file and the test);
            nothing is written.
        """
        with self.transaction() as tx:
            stored = tx.stored(digests)
            same = _check_same(digests, stored)
            new = digests[~same].reset_index(drop=True)
            if len(new):
                tx.write(_rows_of(table, digests, same), new)
                tx.commit()
        return Added(new, digests[same].reset_index(drop=True))

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
