"""Regenerate the example LDBB file: ``python experiments/data/stiffness/regenerate.py``.

The machine twin of the volumetric paper (``models.physics.machine.paper_machine``) with its
stiffness (``models.physics.loaded_circles.paper_stiffness``: column, saddle, and a ram whose
compliance grows with the cube of its extension below z = 200 mm): loaded circles in XY, R
150 mm, F 1000 mm/min, CCW, 72 readings a turn, at 27 centres (three x, y and heights) and
loads 100, 300 and 500 N, 0.2 um reading noise (seed 2026). ``truth.json`` beside it holds
each centre's compliance and stiffness.
"""

import json
from pathlib import Path

from models.physics import loaded_circles as lc
from models.physics import machine as twin

if __name__ == "__main__":
    here = Path(__file__).parent
    machine = twin.paper_machine()
    stiffness = lc.paper_stiffness(machine)
    table, truth = lc.ldbb_campaign(machine, stiffness, lc.centre_grid(machine),
                                    directions=("CCW",), points=72, noise_um=0.2, seed=2026)
    table = table.assign(visit="2026-05", angle_deg=table["angle_deg"].round(3),
                         deviation_um=table["deviation_um"].round(3))
    table.to_csv(here / "ldbb.csv", index=False)
    (here / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
