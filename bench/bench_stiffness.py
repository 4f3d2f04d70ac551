"""Stiffness from loaded circles: 27 centres x 3 loads x 2 directions (360 readings a turn,
58,320 readings), the whole job (``pipeline.workflows.stiffness``: reading and checking the
file, the per-centre regressions, the cross-validated map) against the floor of reading the
same file (``features.readings.formats.read_table``, the CSV as text), as a ratio.

No goal is judged: the ratio is the figure, with the share of the contract's checks (reading
and checking the table as ``backlash circle`` does, ``features.loaded_circles``) beside it.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

from bench import size

REPEATS = size(3, 1)


def _best(run) -> float:
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    from features.loaded_circles import read_loaded_circles
    from features.readings.formats import read_table
    from pipeline.workflows.stiffness import stiffness
    from tests.independent_ldbb import grid_centres, ldbb_table

    centres = grid_centres()[:size(27, 6)]
    table = ldbb_table(seed=0, centres=centres, readings=size(360, 36))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "ldbb.csv"
        table.to_csv(path, index=False)
        floor = _best(lambda: read_table(path))
        checked = _best(lambda: read_loaded_circles(path))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            job = _best(lambda: stiffness(path, ram_top_mm=0.0))
    ratio = job / floor
    print(f"stiffness of {len(centres)} centres x 3 loads x 2 directions ({len(table):,} "
          f"readings): {job:.2f} s; reading the file {floor:.2f} s; ratio {ratio:.1f} "
          f"(reading and checking the contract {checked:.2f} s, {100 * checked / job:.0f} % "
          "of the job)")
