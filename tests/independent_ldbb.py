"""Loaded double-ballbar circles written without the product's twin or models: the truth the
stiffness tests check against.

The machine here is its own: a column with principal stiffnesses along axes turned by a
small angle, a table whose guideways soften towards the end of the X travel, and a ram built
as an Euler-Bernoulli cantilever of bending stiffness EI per direction, whose deflection under
a lateral force F at its extension e is F e^3 / (3 EI). Its load-independent signature is a
play on each axis (half a step either way where the axis reverses, the sign set by the
direction of travel), an out-of-squareness ellipse and a pivot set-up offset drawn afresh for
every run. Readings are white noise on top.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

RAM_TOP_MM = 0.0
HEIGHTS_MM = (-100.0, -350.0, -600.0)
XS_MM, YS_MM = (200.0, 500.0, 800.0), (100.0, 400.0, 700.0)
LOADS_N = (100.0, 300.0, 500.0)
# The column: principal stiffnesses [N/um] along axes turned by this angle from X
COLUMN_K_N_PER_UM = (70.0, 55.0)
COLUMN_TURN_RAD = 0.35
# The table: compliance along X added per mm from the middle of the X travel [um/N/mm]
TABLE_UM_PER_N_PER_MM = 1.5e-5
TABLE_MIDDLE_MM = 500.0
# The ram: bending stiffness EI [N mm^2] for a force along X and along Y
RAM_EI_N_MM2 = (3.0e12, 2.4e12)
PLAY_UM = (4.0, 2.5)
SQUARENESS_UM_PER_M = 12.0


def compliance_um_per_n(point_mm) -> np.ndarray:
    """The XY compliance at each point (n, 3) [mm], shape (n, 2, 2) [um/N]."""
    p = np.atleast_2d(np.asarray(point_mm, float))
    c, s = np.cos(COLUMN_TURN_RAD), np.sin(COLUMN_TURN_RAD)
    turn = np.array([[c, -s], [s, c]])
    column = turn @ np.diag([1.0 / k for k in COLUMN_K_N_PER_UM]) @ turn.T
    out = np.repeat(column[None], len(p), axis=0)
    out[:, 0, 0] += TABLE_UM_PER_N_PER_MM * (p[:, 0] - TABLE_MIDDLE_MM)
    extension = RAM_TOP_MM - p[:, 2]
    for i, ei in enumerate(RAM_EI_N_MM2):
        # mm/N from e^3 / (3 EI); 1 mm = 1000 um
        out[:, i, i] += extension ** 3 / (3.0 * ei) * 1000.0
    return out


def grid_centres() -> np.ndarray:
    """27 centres: three x, three y, three heights [mm]."""
    return np.array([(x, y, z) for z in HEIGHTS_MM for y in YS_MM for x in XS_MM])


def unmeasured_centres() -> np.ndarray:
    """Six centres between the measured ones, none on their grid [mm]."""
    return np.array([(350.0, 250.0, -225.0), (650.0, 550.0, -475.0), (420.0, 610.0, -150.0),
                     (720.0, 180.0, -540.0), (300.0, 450.0, -400.0), (560.0, 330.0, -300.0)])


def _signature(theta: np.ndarray, direction: str, radius_mm: float) -> np.ndarray:
    """Radial deviation of play and squareness [um], load-independent."""
    s = 1.0 if direction == "CCW" else -1.0
    # an axis moving towards + trails by play/2: x' = x - sign(vx) b/2
    vx, vy = -s * np.sin(theta), s * np.cos(theta)
    ex = -np.sign(vx) * PLAY_UM[0] / 2 + SQUARENESS_UM_PER_M * radius_mm / 1000.0 * np.sin(theta)
    ey = -np.sign(vy) * PLAY_UM[1] / 2
    return ex * np.cos(theta) + ey * np.sin(theta)


def ldbb_runs(seed: int = 0, centres=None, loads_n=LOADS_N, directions=("CCW", "CW"),
              radius_mm: float = 100.0, readings: int = 360, noise_um: float = 0.3):
    """Per centre: (centre [mm], runs), each run (direction, load [N], angle [deg], radial
    deviation [um])."""
    rng = np.random.default_rng(seed)
    centres = grid_centres() if centres is None else np.atleast_2d(centres)
    angle = np.arange(readings) * 360.0 / readings
    theta = np.radians(angle)
    u = np.column_stack([np.cos(theta), np.sin(theta)])
    out = []
    for centre in centres:
        # the bar reads u^T C u at each point of the circle
        where = np.column_stack([centre[0] + radius_mm * u[:, 0],
                                 centre[1] + radius_mm * u[:, 1], np.full(readings, centre[2])])
        c = compliance_um_per_n(where)
        radial = np.einsum("ni,nij,nj->n", u, c, u)
        runs = []
        for load in loads_n:
            for direction in directions:
                offset = rng.normal(0.0, 3.0, 2)  # the pivot set afresh for every run
                deviation = (load * radial + _signature(theta, direction, radius_mm)
                             + offset[0] * np.cos(theta) + offset[1] * np.sin(theta)
                             + rng.normal(0.0, noise_um, readings))
                runs.append((direction, float(load), angle, deviation))
        out.append((centre, runs))
    return out


def ldbb_table(seed: int = 0, centres=None, loads_n=LOADS_N, directions=("CCW", "CW"),
               radius_mm: float = 100.0, readings: int = 360, noise_um: float = 0.3,
               machine_id: str = "VMC-7") -> pd.DataFrame:
    """The loaded circles at every centre, load and direction (data contract section 12)."""
    frames = []
    for k, (centre, runs) in enumerate(ldbb_runs(seed, centres, loads_n, directions,
                                                 radius_mm, readings, noise_um)):
        for direction, load, angle, deviation in runs:
            frames.append(pd.DataFrame({
                "test_id": f"{machine_id}-{k:02d}-{load:g}-{direction}",
                "machine_id": machine_id, "plane": "XY", "direction": direction,
                "angle_deg": angle, "radius_mm": radius_mm, "feed_mm_min": 500.0,
                "deviation_um": deviation, "load_n": load, "centre_x_mm": centre[0],
                "centre_y_mm": centre[1], "centre_z_mm": centre[2]}))
    return pd.concat(frames, ignore_index=True)


def true_stiffness(centres) -> np.ndarray:
    """1 / c_xx and 1 / c_yy at each centre, shape (n, 2) [N/um]."""
    c = compliance_um_per_n(centres)
    return 1.0 / np.stack([c[:, 0, 0], c[:, 1, 1]], axis=1)


def true_deflection_um(points, force_n) -> np.ndarray:
    """C(p) F in XY [um], shape (n, 2)."""
    return np.einsum("nij,nj->ni", compliance_um_per_n(points), np.atleast_2d(force_n))
