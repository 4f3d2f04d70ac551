"""Real-like ISO 230-2 tests written by hand (not by the twin): a mean error along the
axis and a reversal value given per target, read with an indirect or a direct measuring
system, ISO 230-2 cycles, Gaussian reading noise.

- ``indirect_stage``: a 9-target +-20 mm stage whose reversal value is -16 to -34 um at every
  target (a clearance varying along the screw, seen by a rotary encoder at every target);
- ``sign_changing``: a 5-target axis whose reversal value changes sign along the axis
  (+18, -14, -24, +10, +20 um: not a clearance), with a lead error curve.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def iso_test(targets, mean_um, reversal_um, noise_um, system="indirect", cycles=5, seed=0,
             clearance_um=0.0, method="linear", test_id="lin-1") -> pd.DataFrame:
    """Readings of one test: the + approach reads ``mean + B / 2``, the - approach
    ``mean - B / 2`` (B the reversal value at the target [um]). A direct system adds the
    clearance ``clearance_um`` only to readings that follow a reversal (a linear test's first
    target +, last target -; every pendulum reading)."""
    rng = np.random.default_rng(seed)
    targets = np.asarray(targets, float)
    n = len(targets)
    if method == "linear":
        one = [(i, 1.0) for i in range(n)] + [(i, -1.0) for i in reversed(range(n))]
    else:
        one = [(i, d) for i in range(n) for d in (1.0, -1.0)]
    rows = []
    for c in range(1, cycles + 1):
        for i, sign in one:
            value = mean_um[i] + sign * reversal_um[i] / 2
            turn = method == "pendulum" or (i == 0 and sign > 0) or (i == n - 1 and sign < 0)
            if system == "direct" and turn:
                value -= sign * clearance_um / 2
            rows.append({"machine_id": "STAGE", "axis": "X", "test_id": test_id,
                         "method": method, "target": targets[i],
                         "direction": "+" if sign > 0 else "-", "cycle": c,
                         "deviation_um": round(value + rng.normal(0, noise_um), 3),
                         "visit": "1", "repeat": 1})
    return pd.DataFrame(rows)


def indirect_stage(seed: int = 0) -> pd.DataFrame:
    """9 targets, -20 to +20 mm; reversal value -16 to -34 um at every target; a cubic lead
    error of +-140 um at the ends (its residual after a straight line is large at the ends,
    where a direct system's lost motion would sit); 3 um noise."""
    x = np.linspace(-20.0, 20.0, 9)
    reversal = np.array([-16.0, -19.0, -24.0, -30.0, -34.0, -31.0, -26.0, -21.0, -18.0])
    mean = 0.3 * x + 140.0 * (x / 20.0) ** 3
    return iso_test(x, mean, reversal, 3.0, "indirect", seed=seed)


def sign_changing(seed: int = 0, system: str = "indirect") -> pd.DataFrame:
    """5 targets, 0 to 400 mm; reversal value +18, -14, -24, +10, +20 um; an S-shaped lead
    error; 5 um noise."""
    x = np.linspace(0.0, 400.0, 5)
    reversal = np.array([18.0, -14.0, -24.0, 10.0, 20.0])
    mean = 0.02 * x + 12.0 * np.tanh((x - 200.0) / 80.0)
    return iso_test(x, mean, reversal, 5.0, system, seed=seed, clearance_um=6.0)
