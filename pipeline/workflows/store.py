"""Store check: verify that a fleet store holds exactly what was ingested.

>>> import backlash as bl
>>> checked = bl.check_store("fleet/")                  # doctest: +SKIP
>>> checked.problems                                    # doctest: +SKIP

Every recorded test's readings are read back and compared with the manifest (their count and
their digest); on the embedded store also every recorded part (present, readable, as many
readings as recorded) and every file under ``readings/`` (named by the manifest). ``repair``
mends only what is provably safe: a test whose readings another recorded part holds intact
is relinked to it, a file the manifest does not name and a recorded part that no test reads
and that holds nothing the store lacks are removed. See ``docs/store.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.results import Result
from pipeline.steps.parameters import STORE, Param

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["check", "{store}"],
    {"store": "{store}"},
)

PARAMETERS = {
    "store": STORE,
    "repair": Param(("boolean",)),
}


@dataclass
class StoreCheckResult(Result):
    """What a check found.

    Attributes
    ----------
    store : str
        The store's location (a URL without its password).
    tests, readings : int
        Tests in the manifest (voided ones included) and the readings recorded for them.
    problems : list of str
        One line per problem left (after a repair, those it could not mend).
    repaired : list of str
        One line per problem the repair mended.
    """

    store: str
    tests: int = 0
    readings: int = 0
    problems: list[str] = field(default_factory=list)
    repaired: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict:
        return {"store": self.store, "ok": self.ok, "tests": self.tests,
                "readings": self.readings, "problems": self.problems, "repaired": self.repaired}


def check_store(store, *, repair: bool = False, progress=None) -> StoreCheckResult:
    """Verify a fleet store against its manifest; optionally mend what is provably safe.

    Parameters
    ----------
    store : str or path-like
        A store folder or a ``postgresql://USER@HOST/DB`` URL.
    repair : bool
        Relink tests to the recorded part that holds their readings intact, remove the
        provably orphaned files (the manifest does not name them) and recorded parts (no test
        reads them), under the store's write lock. Nothing else is ever changed.
    progress : callable, optional
        Unused (a check reads the store once); accepted as every workflow does.

    Returns
    -------
    StoreCheckResult

    Raises
    ------
    InputError
        A location that is no store or cannot be opened.
    """
    # ``store`` opened by the runner, for writing with ``repair`` (``Workflow.store_access``)
    checked = store.check(repair=repair)
    return StoreCheckResult(store=store.location, tests=checked.tests, readings=checked.readings,
                            problems=checked.problems, repaired=checked.repaired)
