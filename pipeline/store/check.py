"""What ``backlash store check`` finds: every recorded test's readings present and as the
manifest says (count and digest), every part recorded and readable, nothing on disk that the
manifest does not name, and every replaced test (``ingest --replace``) holding the readings its
last replacement recorded in the audit. The engines gather the facts (``FolderStore.check``,
``PostgresStore.check``); this module holds the result and the comparisons they share."""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.store.base import KEYS


@dataclass
class Checked:
    """The outcome of a check.

    Attributes
    ----------
    tests : int
        Tests in the manifest (voided ones included).
    readings : int
        Readings the manifest records for them.
    problems : list of str
        One line per problem still there (after ``repaired``).
    repaired : list of str
        One line per problem a repair mended.
    """

    tests: int = 0
    readings: int = 0
    problems: list[str] = field(default_factory=list)
    repaired: list[str] = field(default_factory=list)


def name(test) -> str:
    """A test as the messages name it (``test`` has the ``KEYS`` as attributes)."""
    return (f"test {test.test_id!r} (machine {test.machine_id}, axis {test.axis}, "
            f"visit {test.visit})")


def found_digests(table):
    """Digest rows (``KEYS``, ``sha256``, ``readings``) of the tests a store table holds, in
    any row order (sorted here as ``content.digests`` needs)."""
    import pandas as pd

    from pipeline.store.content import digests

    if table is None or table.num_rows == 0:
        return pd.DataFrame(columns=[*KEYS, "sha256", "readings"])
    ordered = table.sort_by([(k, "ascending") for k in (*KEYS, "seq")])
    return digests(ordered)[[*KEYS, "sha256", "readings"]]


def mismatch(test, found) -> str | None:
    """Why the readings ``found`` (a digest row, or None) are not ``test``'s (a manifest row
    with ``sha256`` and ``readings``), or None when they are."""
    if found is None:
        return "no reading of it is stored"
    if int(found.readings) != int(test.readings):
        return f"{int(found.readings)} readings are stored, the manifest records {test.readings}"
    if found.sha256 != test.sha256:
        return "its stored readings differ from those ingested (digest mismatch)"
    return None


def compare(tests, found) -> list[str]:
    """One line per test of the manifest ``tests`` whose readings ``found`` does not hold
    intact, and per test ``found`` holds that the manifest does not know."""
    both = tests.merge(found, on=KEYS, how="outer", suffixes=("", "_found"), indicator="where")
    lines = []
    for row in both.itertuples(index=False):
        if row.where == "right_only":
            lines.append(f"{name(row)}: {row.readings_found} readings are stored for a test "
                         "the manifest does not know")
            continue
        got = None if row.where == "left_only" else _Found(row.sha256_found,
                                                            row.readings_found)
        why = mismatch(row, got)
        if why:
            lines.append(f"{name(row)}: {why}")
    return lines


@dataclass
class _Found:
    sha256: str
    readings: int


def replacement_problems(tests, replacements: list[tuple]) -> list[str]:
    """One line per replaced test whose digest in the manifest is not the one its last
    replacement recorded in the audit (``tables.replacements`` rows), or that the manifest
    no longer holds: the manifest was changed outside backlash since."""
    last = {tuple(r[:4]): r for r in replacements}  # oldest first: the last one wins
    held = {tuple(getattr(t, k) for k in KEYS): t.sha256 for t in tests.itertuples(index=False)}
    lines = []
    for key, (machine, axis, visit, test_id, at, user, _, _, sha) in sorted(last.items()):
        test = _Key(machine, axis, visit, test_id)
        if key not in held:
            lines.append(f"{name(test)}: replaced on {at} by {user}, but the manifest no longer "
                         "holds it")
        elif held[key] != sha:
            lines.append(f"{name(test)}: its digest is not the one its replacement on {at} by "
                         f"{user} recorded: the manifest was changed outside backlash")
    return lines


def superseded(replacements: list[tuple]) -> set[tuple]:
    """(``KEYS``..., digest) of every reading set a replacement superseded: kept as history in
    the part that held it, never an orphan."""
    return {(*r[:4], r[7]) for r in replacements}


@dataclass
class _Key:
    machine_id: str
    axis: str
    visit: str
    test_id: str
