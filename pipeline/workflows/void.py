"""Void: retire tests of a fleet store (a wrong setup, a test on the wrong axis) without
deleting them.

>>> import backlash as bl
>>> bl.void("fleet/", machine="M01", axis="X", visit="03", reason="laser misaligned")  # doctest: +SKIP

A voided test stays in the store; every reader skips it. The store's audit table keeps each
void and undo with its time (UTC), the operating-system user and the reason; ``undo=True``
restores the tests. See ``docs/store.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from features.readings.errors import InputError
from pipeline.results import Result
from pipeline.steps.parameters import STORE, Param

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{store}", "--machine", "M01", "--axis", "Y", "--visit", "01", "--reason", "r"],
    {"store": "{store}", "machine": "M01", "axis": "Y", "visit": "01", "reason": "r"},
)

PARAMETERS = {
    "store": STORE,
    "machine": Param((str,), metavar="ID", required=True),
    "axis": Param((str,), metavar="AXIS", required=True),
    "visit": Param((str, None), metavar="VISIT"),
    "test_id": Param((str, None), metavar="TEST"),
    "reason": Param((str,), metavar="TEXT", required=True),
    "undo": Param(("boolean",)),
}


@dataclass
class VoidResult(Result):
    """The tests a void retired (or an undo restored).

    Attributes
    ----------
    store : str
        The store's location (a URL without its password).
    action : str
        ``"void"`` or ``"undo"``.
    tests : list of dict
        ``machine_id``, ``axis``, ``visit``, ``test_id`` of each test.
    reason : str
        The reason kept in the audit table.
    """

    store: str
    action: str
    tests: list[dict] = field(default_factory=list)
    reason: str = ""

    def to_dict(self) -> dict:
        return {"store": self.store, "action": self.action, "reason": self.reason,
                "tests": self.tests}

    @property
    def line(self) -> str:
        """What was done, in one line (the command prints it): how many tests of which
        machine axis (and visits, as the store writes them), why, and what readers do now."""
        first = self.tests[0] if self.tests else {"machine_id": "?", "axis": "?"}
        visits = sorted({t["visit"] for t in self.tests})
        done = "restored" if self.action == "undo" else "voided"
        now = "every reader reads them again" if self.action == "undo" else \
            "every reader skips them"
        return (f"{len(self.tests)} tests of machine {first['machine_id']}, axis "
                f"{first['axis']} {done} (visit{'s' if len(visits) > 1 else ''} "
                f"{', '.join(visits)}) in {self.store}: {now}; reason: {self.reason}")


def void(store, *, machine: str, axis: str, visit: str | None = None,
         test_id: str | None = None, reason: str, undo: bool = False,
         progress=None) -> VoidResult:
    """Retire the tests of a machine axis (a visit, one test) from every reader of a store.

    Parameters
    ----------
    store : str or path-like
        A store folder or a ``postgresql://USER@HOST/DB`` URL.
    machine : str
        The machine whose axis's tests are voided.
    axis : str
        The axis whose tests are voided.
    visit : str, optional
        Only this visit's tests.
    test_id : str, optional
        Only this test.
    reason : str
        Why (kept in the store's audit table with the time and the user); not empty.
    undo : bool
        Restore the matching voided tests instead.
    progress : callable, optional
        Unused; accepted as every workflow does.

    Returns
    -------
    VoidResult

    Raises
    ------
    InputError
        An empty reason, no matching test (no matching voided test with ``undo``), a store
        that cannot be opened or written: nothing is changed.
    """
    if not reason.strip():
        raise InputError("is empty; say why the tests are voided", parameter="reason")
    # ``store`` opened for writing by the runner (``Workflow.store_access``)
    if not store.exists():
        raise InputError("no such store", file=store.location)
    keys = store.void(machine, axis, visit, test_id, reason=reason.strip(), undo=undo)
    result = VoidResult(store=store.location, action="undo" if undo else "void",
                        tests=[dict(zip(("machine_id", "axis", "visit", "test_id"), k))
                               for k in keys], reason=reason.strip())
    return result  # what was done is the result (``line``), not a note beside it
