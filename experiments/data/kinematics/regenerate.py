"""Regenerate the example probing table from the tests' independent generator
(``tests/independent_probing.py``): two A-C machines, two spheres, A -30..90, C 0..330, both
approach directions, probe noise 0.8 um. ``truth.json`` holds what was put in.

    python experiments/data/kinematics/regenerate.py
"""

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))

from tests import independent_probing as ip

points = ip.workpiece_points()
machines = [ip.machine(k, top, points) for k, top in enumerate((46.0, 72.0))]
frame = __import__("pandas").concat([ip.probing(m, seed=k) for k, m in enumerate(machines)],
                                    ignore_index=True)
frame.round(6).to_csv(HERE / "probes.csv", index=False)
points.iloc[:24].round(3).to_csv(HERE / "points.csv", index=False)
(HERE / "truth.json").write_text(json.dumps({"machines": machines}, indent=2) + "\n")
