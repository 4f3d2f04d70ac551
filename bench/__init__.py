"""Benchmarks run by ``make bench``: each ``bench_*`` module has ``main()`` printing its figures.

``BACKLASH_BENCH_TINY=1`` runs every module at tiny sizes (``tests/test_bench.py``), so a
benchmark that no longer runs is caught by the tests; its figures are then no measurement and
its goals are not judged. Each module takes its sizes through ``size``, so the full run is
unchanged.
"""

import os

TINY = os.environ.get("BACKLASH_BENCH_TINY") == "1"
TINY_NOTE = "tiny run: figures not a measurement"


def size(full, tiny):
    """``tiny`` in a tiny run, else ``full``: a count of tests, machines, trials, repeats..."""
    return tiny if TINY else full


def verdict(passed: bool) -> str:
    """PASS or FAIL against a goal; a tiny run judges nothing."""
    if TINY:
        return "not judged"
    return "PASS" if passed else "FAIL"
