"""Ingest: validate readings files and append their tests to a fleet store.

>>> import backlash as bl
>>> result = bl.ingest(["visit01.csv", "ess_mcu1025_ISO230.dat"], store="fleet/")  # doctest: +SKIP
>>> result.added, result.unchanged                                               # doctest: +SKIP
>>> readings = bl.read("fleet/", machine="M01", since="2026-01-01")               # doctest: +SKIP

Every file goes through the readers of every other job (any accepted layout, one validation).
A test is its key (machine_id, axis, visit, test_id) and its readings: ingesting the same test
again changes nothing (a note says so); a key already stored with other readings is refused
and the whole ingest with it. All files are added in one transaction, or none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from features.readings.errors import InputError, note
from pipeline.results import Result
from pipeline.steps.parameters import FORMAT, READINGS, Param, readings
from pipeline.workflows import check_params, readings_of

PARAMETERS = {
    "files": readings(flag="FILE", accepts=(*READINGS, list, tuple), nargs="+"),
    "format": FORMAT,
    "store": Param((str, os.PathLike), "store folder (created when new or empty) or "
                   "postgresql://USER@HOST/DB (password in ~/.pgpass or PGPASSWORD, not in the "
                   "URL)", metavar="STORE", required=True),
}


@dataclass
class IngestResult(Result):
    """What an ingest added to a store.

    Attributes
    ----------
    store : str
        The store's location (a URL without its password).
    inputs : list of dict
        Per input file: ``file``, ``readings``, ``tests``, ``added`` and ``unchanged``
        (tests).
    added : int
        Tests written to the store.
    unchanged : int
        Tests already stored with the same readings (left as they were).
    readings_added : int
        Readings written to the store.
    tests_in_store : int
        Tests in the store after the ingest.
    """

    store: str
    inputs: list[dict] = field(default_factory=list)
    added: int = 0
    unchanged: int = 0
    readings_added: int = 0
    tests_in_store: int = 0

    def to_json(self) -> dict:
        return {"store": self.store, "files": self.inputs, "added": self.added,
                "unchanged": self.unchanged, "readings_added": self.readings_added,
                "tests_in_store": self.tests_in_store}


def ingest(files, store, *, format: str = "auto", progress=None) -> IngestResult:
    """Validate readings files and add their tests to a fleet store, in one transaction.

    Parameters
    ----------
    files : str, path-like, DataFrame or list of them
        Readings files in any accepted layout, or frames ``read`` returned.
    store : str or path-like
        A store folder (created when it does not exist or is empty) or a
        ``postgresql://user@host/database`` URL (tables created by the first ingest; give
        the password in ``~/.pgpass`` or ``PGPASSWORD`` rather than in the URL).
    format : str
        Layout of the files, ``"auto"`` to recognise each one.
    progress : callable, optional
        ``progress(done, total, what)`` after each file read.

    Returns
    -------
    IngestResult

    Raises
    ------
    InputError
        A file that cannot be read or breaks the readings contract, a test already stored
        with other readings, a store that cannot be opened or written: nothing is written.
    """
    check_params(PARAMETERS, {"files": files, "store": store, "format": format}, "ingest")
    from pipeline.store import open_store, redact

    inputs = _inputs(files)
    target = open_store(store, write=True, parameter="store")  # refused before any reading
    tables, digests, per_file = _read_all(inputs, format, progress)
    import pandas as pd
    import pyarrow as pa

    added = target.add(pa.concat_tables(tables), pd.concat(digests, ignore_index=True))
    result = IngestResult(store=redact(store), inputs=per_file, added=len(added.new),
                          unchanged=len(added.same) + _repeated(per_file),
                          readings_added=int(added.new["readings"].sum()),
                          tests_in_store=target.count())
    _count_per_file(result, added)
    for text in _notes(result):
        result.notes.append(text)
        note(text)
    return result


def _inputs(files) -> list:
    """``files`` as a non-empty list."""
    items = list(files) if isinstance(files, (list, tuple)) else [files]
    if not items:
        raise InputError("is empty; expected one or more readings files", parameter="files")
    return items


def _read_all(inputs: list, format: str, progress) -> tuple[list, list, list[dict]]:
    """Store tables, digests and a summary per input; a test given twice with the same
    readings is kept once, with other readings it is refused."""
    from features.readings.errors import report
    from pipeline.store import content

    tables, digests, per_file, seen = [], [], [], {}
    for i, item in enumerate(inputs):
        readings = readings_of(item, format, "files")
        name = readings.attrs.get("source", f"files[{i}]")
        extra = content.extra_columns(readings)
        if extra:
            note(f"{name}: columns {', '.join(extra)} are not in the readings contract; the "
                 "store does not keep them")
        table = content.store_table(readings)
        found = content.digests(table)
        found["file"] = name
        keep = _first_time(found, seen)
        tables.append(table if keep.all() else _tests_of(table, found[keep]))
        digests.append(found[keep])
        per_file.append({"file": name, "readings": len(readings), "tests": len(found),
                         "added": 0, "unchanged": int((~keep).sum())})
        report(progress, i + 1, len(inputs), name)
    return tables, digests, per_file


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
    for f in result.inputs:
        f["added"] = int(new.get(f["file"], 0))
        f["unchanged"] += int(same.get(f["file"], 0))


def _notes(result: IngestResult) -> list[str]:
    notes = [f"{f['file']}: {f['unchanged']} of {f['tests']} tests already in the store with "
             "the same readings; left unchanged" for f in result.inputs if f["unchanged"]]
    if not result.added:
        notes.append(f"nothing changed: every test is already in the store {result.store}")
    return notes
