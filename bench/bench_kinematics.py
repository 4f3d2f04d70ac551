"""kinematics on 4 A-C machines x 1,700 probed centres against the floor of reading the file.

The floor is what any job pays for the same table: reading the CSV and checking it against the
contract (``features.probing.read_probes``). The ratio says what the identification, the rank,
Tables 4-5 and the notes add on top of it.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

MACHINES, POINTS = 4, 1_700


def _probes(folder: Path) -> Path:
    import numpy as np

    from models.physics import rotary_probing as rp

    # 2 spheres x 9 A x 48 C x 2 directions = 1,728 centres per machine
    machines = [rp.random_machine(k) for k in range(MACHINES)]
    return rp.write_run(folder, machines, seed=0, c_deg=tuple(np.arange(0.0, 360.0, 7.5))
                        )["probes"]


def _best(fn, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    import pandas as pd

    from features.probing import read_probes
    from pipeline.workflows.kinematics import kinematics

    with tempfile.TemporaryDirectory() as tmp:
        path = _probes(Path(tmp))
        rows = len(pd.read_csv(path))
        floor = _best(lambda: read_probes(path))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            job = _best(lambda: kinematics(path))
    print(f"kinematics of {MACHINES} machines x {rows // MACHINES} centres: {job:.3f} s; "
          f"reading the file {floor:.3f} s; ratio {job / floor:.1f}")


if __name__ == "__main__":
    main()
