"""Regenerate the example ballbar file: ``python experiments/data/circle/regenerate.py``.

One machine, plane XY, R 150 mm, F 1000 mm/min, a CCW and a CW run, made by the independent
ballbar generator of the tests (``tests/independent_circle.py``, seed 2026): a play and a
friction spike per axis, out-of-squareness, scale and servo mismatch, the pivot off centre,
drift and noise. ``truth.json`` beside it holds what was put in.
"""

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from tests.independent_circle import ballbar_run, random_truth

if __name__ == "__main__":
    here = Path(__file__).parent
    rng = np.random.default_rng(2026)
    truth = random_truth(rng, "VMC-7")
    rows = []
    for direction in ("CCW", "CW"):
        run = ballbar_run(truth, direction, step_deg=1.0173, rng=rng)
        rows.append(run.round(3).assign(
            test_id=f"VMC-7-XY-{direction}", machine_id="VMC-7", plane="XY",
            direction=direction, radius_mm=150.0, feed_mm_min=1000.0, visit="2026-03",
            started_at="2026-03-02T09:10:00Z" if direction == "CCW" else "2026-03-02T09:12:00Z"))

    table = pd.concat(rows, ignore_index=True)[
        ["test_id", "machine_id", "plane", "direction", "angle_deg", "radius_mm",
         "feed_mm_min", "deviation_um", "visit", "started_at"]]
    table.to_csv(here / "ballbar_xy.csv", index=False)
    plain = {k: (list(map(float, v)) if isinstance(v, tuple) else v)
             for k, v in asdict(truth).items()}
    (here / "truth.json").write_text(json.dumps(plain, indent=2) + "\n")
    print(f"wrote {here / 'ballbar_xy.csv'} ({len(table)} readings)")
