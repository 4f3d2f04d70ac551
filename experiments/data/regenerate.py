"""Regenerate the demo's embedded twin data set: ``python experiments/data/regenerate.py``.

The ``demo`` preset (one machine, axis X, direct measuring system, the paper plan with one
repeat, six visits 45 days apart with wear) at seed 2026, written to ``experiments/data/twin/``.
"""

from pathlib import Path

from models.physics.campaign import simulate
from pipeline.commands.simulate import write

if __name__ == "__main__":
    out = Path(__file__).parent / "twin"
    write(simulate("demo", seed=2026), out)
    print(f"wrote {out}")
