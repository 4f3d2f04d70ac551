"""Laser tests of a three-axis machine, written independently of the twin (it never imports
``models.physics``): its own error shapes (polynomials and exponentials, not the twin's sines),
its own first-order error of a spindle point written out by components, its own play and noise.

Conventions shared with the product (ISO 230-1): positions [mm], translations [um], angles
[urad]; positioning and angles zero at the start of travel, straightness without its
least-squares line, squareness separately: E_x += a_XY y + a_XZ z, E_y += a_YZ z. The tables
(X on Y) carry the workpiece and enter with a minus sign, their angles acting about reading
heads fixed in the bed over the lever h + z e_z - R; the ram's about its own reading head over
h - R_Z.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

AXES = ("X", "Y", "Z")
CHANNELS = ("dx_um", "dy_um", "dz_um", "ex_urad", "ey_urad", "ez_urad")
TRAVEL = {"X": (0.0, 1000.0), "Y": (-800.0, 0.0), "Z": (-600.0, 0.0)}
HEADS = {"X": np.array([0.0, -250.0, -900.0]), "Y": np.array([-400.0, 0.0, -950.0]),
         "Z": np.array([0.0, 300.0, 0.0])}
TOOL = np.array([0.0, 0.0, -180.0])
LASER = {"X": np.array([0.0, 200.0, 100.0]), "Y": np.array([-200.0, 0.0, 100.0]),
         "Z": np.array([150.0, 150.0, -100.0])}
ORIGIN = np.array([500.0, -400.0, -300.0])
SQUARENESS = {"XY": -18.0, "XZ": 10.0, "YZ": 25.0}
# per axis, per channel: (a, b, c, k) of a u + b u^2 + c (1 - exp(-k u)) on u in [0, 1]
SHAPES = {
    "X": [(30, -20, 0, 1), (8, -8, 3, 4), (-5, 5, 2, 3), (6, -4, 0, 1), (-40, 10, 8, 5),
          (30, -10, -5, 3)],
    "Y": [(-15, 25, 0, 1), (-6, 6, -3, 4), (4, -4, 3, 2), (-20, 10, 0, 1), (9, -3, -4, 6),
          (-8, 2, 5, 3)],
    "Z": [(25, 15, -6, 3), (10, -10, 4, 5), (-12, 12, 0, 1), (30, -10, 0, 1), (-15, 20, 3, 2),
          (12, -4, 0, 1)],
}


def truth(axis: str, q_mm) -> np.ndarray:
    """The six error motions of ``axis`` at ``q_mm``, shape (n, 6), in the shared conventions."""
    lo, hi = TRAVEL[axis]
    u = (np.atleast_1d(np.asarray(q_mm, float)) - lo) / (hi - lo)
    dense = np.linspace(0.0, 1.0, 2001)
    j = AXES.index(axis)
    columns = []
    for c, (a, b, cc, k) in enumerate(SHAPES[axis]):
        f = lambda v, a=a, b=b, cc=cc, k=k: a * v + b * v**2 + cc * (1 - np.exp(-k * v))
        if c < 3 and c != j:  # straightness: remove the least-squares line over the travel
            slope, offset = np.polyfit(dense, f(dense), 1)
            columns.append(f(u) - slope * u - offset)
        else:
            columns.append(f(u) - f(0.0))
    return np.stack(columns, axis=1)


def _cross(e, lever):
    """e x lever by components, e [urad], lever [mm] -> [um]."""
    return 1e-3 * np.stack([e[:, 1] * lever[:, 2] - e[:, 2] * lever[:, 1],
                            e[:, 2] * lever[:, 0] - e[:, 0] * lever[:, 2],
                            e[:, 0] * lever[:, 1] - e[:, 1] * lever[:, 0]], axis=1)


def point_error(position_mm, point_mm) -> tuple[np.ndarray, np.ndarray]:
    """Translation [um] and relative angles [urad] of a spindle point against the workpiece."""
    p = np.atleast_2d(position_mm)
    trans, angle = np.zeros_like(p), np.zeros_like(p)
    for i, axis in enumerate(AXES):
        six = truth(axis, p[:, i])
        delta, eps = six[:, :3], six[:, 3:]
        lever = np.tile(point_mm - HEADS[axis], (len(p), 1))
        if axis == "Z":
            trans += delta + _cross(eps, lever)
            angle += eps
        else:
            lever[:, 2] += p[:, 2]
            trans -= delta + _cross(eps, lever)
            angle -= eps
    trans[:, 0] += 1e-3 * (SQUARENESS["XY"] * p[:, 1] + SQUARENESS["XZ"] * p[:, 2])
    trans[:, 1] += 1e-3 * SQUARENESS["YZ"] * p[:, 2]
    return trans, angle


def axis_tests(rng, targets: int = 11, cycles: int = 5, backlash_um: float = 5.0,
               noise=(0.3, 0.5, 0.3, 1.0)) -> dict:
    """Each axis' six-channel laser test at its optics: axis -> frame with ``cycle``,
    ``direction``, ``target``, ``distance_mm`` and the six channels, zeroed at the first
    reading. ``noise``: positioning, straightness [um], pitch/yaw, roll [urad]."""
    out = {}
    for j, axis in enumerate(AXES):
        lo, hi = TRAVEL[axis]
        distance = np.linspace(0.0, hi - lo, targets)
        rows = []
        for cycle in range(1, cycles + 1):
            for direction in (1, -1):
                for t in range(targets)[::direction]:
                    rows.append((cycle, direction, t, distance[t]))
        frame = pd.DataFrame(rows, columns=["cycle", "direction", "target", "distance_mm"])
        position = np.tile(ORIGIN, (len(frame), 1))
        position[:, j] = lo + frame["distance_mm"].to_numpy()
        trans, angle = point_error(position, LASER[axis])
        trans[:, j] -= frame["direction"].to_numpy() * backlash_um / 2  # the table lags
        values = np.hstack([trans, angle])
        values -= values[0]
        sd = np.full(6, noise[1])
        sd[j], sd[3:], sd[3 + j] = noise[0], noise[2], noise[3]
        frame[list(CHANNELS)] = values + rng.normal(size=values.shape) * sd
        out[axis] = frame
    return out
