"""Ingest: validate readings files and append their tests to a fleet store.

>>> import backlash as bl
>>> result = bl.ingest(["visit01.csv", "ess_mcu1025_ISO230.dat"], store="fleet/")  # doctest: +SKIP
>>> result.added, result.unchanged                                               # doctest: +SKIP
>>> readings = bl.read("fleet/", machine="M01", since="2026-01-01")               # doctest: +SKIP

Every file goes through the readers of every other job (any accepted layout, one validation).
A test is its key (machine_id, axis, visit, test_id) and its readings: ingesting the same test
again changes nothing (a note says so); a key already stored with other readings is refused
and the whole ingest with it, unless ``replace`` (with a ``reason``) puts the corrected
readings in place, kept in the store's audit. All files are added in one transaction, or
none. What a hurried planner may get wrong is refused before anything is written: a test
dated after today (``allow_future`` keeps it), a column the store would drop
(``allow_unknown_columns`` drops it), a store in a folder that does not exist.
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field

from features.readings.errors import InputError, note
from pipeline.results import Result
from pipeline.steps.parameters import FORMAT, READINGS, Param, readings
from pipeline.steps.source import readings_of

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--store", "{base}/new"],
    {"files": "{two}", "store": "{base}/new"},
)

PARAMETERS = {
    "files": readings(flag="FILE", accepts=(*READINGS, list, tuple), nargs="+"),
    "format": FORMAT,
    "store": Param((str, os.PathLike), metavar="STORE", required=True),
    "allow_future": Param(("boolean",)),
    "allow_unknown_columns": Param(("boolean",)),
    "replace": Param(("boolean",)),
    "reason": Param((str, None), metavar="TEXT"),
}


class IngestInterrupted(KeyboardInterrupt):
    """An ingest stopped (Ctrl-C) before its commit; ``text`` says what the store kept."""

    def __init__(self, text: str):
        super().__init__(text)
        self.text = text


@dataclass
class IngestResult(Result):
    """What an ingest added to a store.

    Attributes
    ----------
    store : str
        The store's location (a URL without its password).
    inputs : list of dict
        Per input file: ``file``, ``readings``, ``tests``, ``added``, ``replaced`` and
        ``unchanged`` (tests).
    added : int
        Tests written to the store.
    unchanged : int
        Tests already stored with the same readings (left as they were).
    readings_added : int
        Readings written to the store.
    tests_in_store : int
        Tests in the store after the ingest.
    replaced : int
        Tests whose readings were replaced (``replace``).
    new_store : bool
        The ingest made the store.
    """

    store: str
    inputs: list[dict] = field(default_factory=list)
    added: int = 0
    unchanged: int = 0
    readings_added: int = 0
    tests_in_store: int = 0
    replaced: int = 0
    new_store: bool = False

    def to_dict(self) -> dict:
        return {"store": self.store, "files": self.inputs, "added": self.added,
                "unchanged": self.unchanged, "replaced": self.replaced,
                "readings_added": self.readings_added, "tests_in_store": self.tests_in_store,
                "new_store": self.new_store}


def ingest(files, store, *, format: str = "auto", allow_future: bool = False,
           allow_unknown_columns: bool = False, replace: bool = False,
           reason: str | None = None, progress=None) -> IngestResult:
    """Validate readings files and add their tests to a fleet store, in one transaction.

    Parameters
    ----------
    files : str, path-like, DataFrame or list of them
        Readings files in any accepted layout, or frames ``read`` returned.
    store : str or path-like
        A store folder (created when it does not exist or is empty, inside an existing
        folder) or a ``postgresql://USER@HOST/DB`` URL (tables created by the first ingest;
        give the password in ``~/.pgpass`` or ``PGPASSWORD``, not in the URL).
    format : str
        Layout of the files, ``"auto"`` to recognise each one.
    allow_future : bool
        Keep tests started after today (UTC; a note names them); refused otherwise, as a
        date with a mistyped year would pass for an axis's latest visit.
    allow_unknown_columns : bool
        Leave out columns outside the readings contract (a note names each with the contract
        column it is closest to); refused otherwise, as the store keeps only the contract: a
        misspelled column would be lost.
    replace : bool
        Put these corrected readings in place of those stored for the same tests (same
        machine, axis, visit and test_id; each test must be stored); needs a reason. The audit
        keeps the time, the user, the reason and both readings' digests. A voided test stays
        voided.
    reason : str, optional
        Why the stored tests are replaced (kept in the store's audit with the time, the user
        and both readings' digests); required when replacing tests, and only then.
    progress : callable, optional
        ``progress(done, total, what)`` after each file read.

    Returns
    -------
    IngestResult

    Raises
    ------
    InputError
        A file that cannot be read or breaks the readings contract, a test started after
        today, a column outside the contract, a test already stored with other readings
        (``replace``: a test not stored), ``replace`` without a reason, a store that cannot be
        opened or written or whose folder's parent does not exist: nothing is written.
    IngestInterrupted
        Interrupted (Ctrl-C) before the commit: nothing was added.
    """
    reason = _reason(replace, reason)
    inputs = _inputs(files)
    # ``store`` opened for writing by the runner (``Workflow.store_access``), before any reading
    location = store.location
    new_store = not store.exists()
    if replace and new_store:
        raise InputError("holds no store yet; --replace replaces tests of an existing store",
                         file=location, parameter="store")
    try:
        tables, digests, per_file, notes = _read_all(inputs, format, progress,
                                                     allow_future, allow_unknown_columns)
        import pandas as pd
        import pyarrow as pa

        added = store.add(pa.concat_tables(tables), pd.concat(digests, ignore_index=True),
                           replace=replace, reason=reason)
    except KeyboardInterrupt:
        raise IngestInterrupted(f"nothing was added to the store {location} (all files "
                                "go in one transaction, or none)") from None
    result = IngestResult(store=location, inputs=per_file, added=len(added.new),
                          unchanged=len(added.same) + _repeated(per_file),
                          readings_added=int(added.new["readings"].sum()),
                          tests_in_store=store.count(),
                          replaced=0 if added.replaced is None else len(added.replaced),
                          new_store=new_store and bool(len(added.new)))
    _count_per_file(result, added)
    for text in notes + _notes(result, added, reason):
        result.notes.append(text)
        note(text)
    return result


def _reason(replace: bool, reason: str | None) -> str | None:
    """The reason of a replacement, checked: required with ``replace``, only with it."""
    if reason is not None and not reason.strip():
        raise InputError("is empty; say why the stored tests are replaced", parameter="reason")
    if replace and reason is None:
        raise InputError("is missing: --replace needs the reason the stored tests are replaced "
                         "(kept in the store's audit)", parameter="reason")
    if reason is not None and not replace:
        raise InputError("applies to --replace only (the reason a stored test's readings are "
                         "replaced); nothing was added", parameter="reason")
    return None if reason is None else reason.strip()


def _inputs(files) -> list:
    """``files`` as a non-empty list."""
    items = list(files) if isinstance(files, (list, tuple)) else [files]
    if not items:
        raise InputError("is empty; expected one or more readings files", parameter="files")
    return items


def _read_all(inputs: list, format: str, progress, allow_future: bool,
              allow_unknown_columns: bool) -> tuple[list, list, list[dict], list[str]]:
    """Store tables, digests, a summary per input and the notes; a test given twice with the
    same readings is kept once, with other readings it is refused."""
    from features.readings.errors import report
    from pipeline.store import content

    tables, digests, per_file, seen, notes = [], [], [], {}, []
    for i, item in enumerate(inputs):
        readings = readings_of(item, format, "files")
        name = readings.attrs.get("source", f"files[{i}]")
        notes += _unknown_columns(content.extra_columns(readings), name, allow_unknown_columns)
        table = content.store_table(readings)
        found = content.digests(table)
        found["file"] = name
        notes += _future(found, name, allow_future)
        keep = _first_time(found, seen)
        tables.append(table if keep.all() else _tests_of(table, found[keep]))
        digests.append(found[keep])
        per_file.append({"file": name, "readings": len(readings), "tests": len(found),
                         "added": 0, "replaced": 0, "unchanged": int((~keep).sum())})
        report(progress, i + 1, len(inputs), name)
    return tables, digests, per_file, notes


def _unknown_columns(extra: list[str], name: str, allowed: bool) -> list[str]:
    """Refuse columns outside the contract (the store would drop them, and the corrected file
    would then be refused as other readings of the same tests); with ``allowed``, a note."""
    if not extra:
        return []
    from features.readings.validation import unknown_columns_text

    text = unknown_columns_text(extra)
    if not allowed:
        raise InputError(f"unknown column{'s' if len(extra) > 1 else ''} {text}; the store "
                         "keeps only the readings contract's columns: rename it, or leave it "
                         "out with --allow-unknown-columns; nothing was added", file=name)
    return [(f"{name}: column{'s' if len(extra) > 1 else ''} {text} left out of the store "
            "(--allow-unknown-columns)")]


def _future(found, name: str, allowed: bool) -> list[str]:
    """Refuse tests started after today (UTC): dated ahead, a test would pass for the axis's
    latest visit; with ``allowed``, a note naming them."""
    import pandas as pd

    today = dt.datetime.now(dt.UTC).date()
    starts = pd.to_datetime(found["started_at"], utc=True)
    later = (starts >= pd.Timestamp(today + dt.timedelta(days=1), tz="UTC")).to_numpy()
    if not later.any():
        return []
    rows = found[later]
    first = rows.iloc[0]
    if not allowed:
        raise InputError(f"test {first['test_id']!r} (machine {first['machine_id']}, axis "
                         f"{first['axis']}, visit {first['visit']}) started on "
                         f"{starts[later].iloc[0].date().isoformat()}, after today "
                         f"({today.isoformat()}); expected a start not in the future (a "
                         "mistyped date?), or keep it with --allow-future; nothing was added",
                         file=name, column="started_at")
    shown = ", ".join(f"{t} ({d.date().isoformat()})"
                      for t, d in zip(rows["test_id"][:5], starts[later][:5]))
    return [(f"{name}: {len(rows)} test(s) started after today ({today.isoformat()}) kept "
            f"(--allow-future): {shown}{' ...' if len(rows) > 5 else ''}; a view as of an "
            "earlier day leaves them out")]


def _first_time(found, seen: dict):
    """Mask of the tests of ``found`` not given by an earlier input (``seen``: key ->
    (digest, file)); a key given earlier with other readings is refused."""
    import numpy as np

    keep = np.ones(len(found), dtype=bool)
    for i, row in enumerate(found.itertuples(index=False)):
        key = (row.machine_id, row.axis, row.visit, row.test_id)
        if key in seen:
            if seen[key][0] != row.sha256:
                raise InputError(f"test {row.test_id!r} (machine {row.machine_id}, axis "
                                 f"{row.axis}, visit {row.visit}) is also in {seen[key][1]} "
                                 "with other readings; nothing was added", file=row.file)
            keep[i] = False
        else:
            seen[key] = (row.sha256, row.file)
    return keep


def _tests_of(table, digests):
    """The rows of ``table`` that belong to the tests of ``digests``."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from pipeline.store.content import KEYS

    key = pc.binary_join_element_wise(*[table[k] for k in KEYS], "\x1f")
    wanted = pa.array(["\x1f".join(k) for k in digests[KEYS].itertuples(index=False)],
                      pa.string())
    return table.filter(pc.is_in(key, value_set=wanted))


def _repeated(per_file: list[dict]) -> int:
    return sum(f["unchanged"] for f in per_file)


def _count_per_file(result: IngestResult, added) -> None:
    new = added.new["file"].value_counts()
    same = added.same["file"].value_counts()
    replaced = ({} if added.replaced is None else added.replaced["file"].value_counts())
    for f in result.inputs:
        f["added"] = int(new.get(f["file"], 0))
        f["replaced"] = int(replaced.get(f["file"], 0))
        f["unchanged"] += int(same.get(f["file"], 0))


def _notes(result: IngestResult, added, reason: str | None) -> list[str]:
    notes = [f"{f['file']}: {f['unchanged']} of {f['tests']} tests already in the store with "
             "the same readings; left unchanged" for f in result.inputs if f["unchanged"]]
    if result.new_store:
        notes.insert(0, f"new store at {result.store}")
    if result.replaced:
        notes.append(f"{result.replaced} test(s) replaced ({reason}): the store's audit keeps "
                     "the time, the user and the digest of the readings replaced")
    for machine, axis, visit, test_id in added.voided:
        notes.append(f"test {test_id!r} (machine {machine}, axis {axis}, visit {visit}) is "
                     "voided and stays voided with its new readings (backlash void --undo "
                     "restores it)")
    if not result.added and not result.replaced:
        notes.append(f"nothing changed: every test is already in the store {result.store}")
    return notes
