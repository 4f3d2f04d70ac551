"""An independent generator of probing tables (data contract section 13): its own homogeneous
transforms, written from seed 003's eq. 6 without the product's twin or model.

Each error transform is a translation times three successive rotations about X, Y and Z by
the angular errors (an Euler product, not the product's Rodrigues rotation: the two agree to
second order, which is the point of an independent check), and each rotary axis reaches its
commanded angle minus direction x play / 2.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

ARCSEC = math.pi / (180 * 3600)
NAMES = [name for axis in "AC" for name in (
    *(f"delta_{t}_{axis}_um" for t in "xyz"),
    *(f"eps_{a}_{axis}_urad" for a in ("alpha", "beta", "gamma")))]
SPHERES = {"ball_1": (140.0, -30.0, 50.0), "ball_2": (-60.0, 120.0, 160.0)}


def rot_x(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def rot_y(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def rot_z(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def shift(v_mm):
    m = np.eye(4)
    m[:3, 3] = v_mm
    return m


def error_htm(errors: dict, axis: str) -> np.ndarray:
    d = [errors[f"delta_{t}_{axis}_um"] * 1e-3 for t in "xyz"]
    e = [errors[f"eps_{a}_{axis}_urad"] * 1e-6 for a in ("alpha", "beta", "gamma")]
    return shift(d) @ rot_x(e[0]) @ rot_y(e[1]) @ rot_z(e[2])


def place(machine: dict, q_mm, a_deg, c_deg, direction=0) -> np.ndarray:
    """Where the table puts q [mm] at commanded (a, c) approached from ``direction``."""
    a = math.radians(a_deg) - direction * machine["play_arcsec"]["A"] / 2 * ARCSEC
    c = math.radians(c_deg) - direction * machine["play_arcsec"]["C"] / 2 * ARCSEC
    chain = (error_htm(machine["errors"], "A") @ rot_x(a) @ error_htm(machine["errors"], "C")
             @ rot_z(c))
    return (chain @ np.r_[q_mm, 1.0])[:3]


def ideal(q_mm, a_deg, c_deg) -> np.ndarray:
    return (rot_x(math.radians(a_deg)) @ rot_z(math.radians(c_deg)) @ np.r_[q_mm, 1.0])[:3]


def workpiece_points(n: int = 192, seed: int = 99, half_mm: float = 200.0) -> pd.DataFrame:
    """``n`` workpiece points in the cube x, y in [-w, w], z in [0, w] with angles A in
    [-30, 90], C in [0, 360)."""
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"x_mm": rng.uniform(-half_mm, half_mm, n),
                         "y_mm": rng.uniform(-half_mm, half_mm, n),
                         "z_mm": rng.uniform(0, half_mm, n), "a_deg": rng.uniform(-30, 90, n),
                         "c_deg": rng.uniform(0, 360, n)})


def true_field(machine: dict, points: pd.DataFrame) -> np.ndarray:
    """dp [um] of each point (no play: the mean of both approach directions)."""
    out = []
    for r in points.itertuples():
        q = np.array([r.x_mm, r.y_mm, r.z_mm])
        both = (place(machine, q, r.a_deg, r.c_deg, 1) + place(machine, q, r.a_deg, r.c_deg, -1))
        out.append((both / 2 - ideal(q, r.a_deg, r.c_deg)) * 1e3)
    return np.array(out)


def machine(seed: int, field_max_um: float, points: pd.DataFrame | None = None) -> dict:
    """Random errors, rescaled so the largest error over ``points`` is ``field_max_um``."""
    rng = np.random.default_rng(1000 + seed)
    errors = {n: float(rng.uniform(-8, 8) if n.endswith("_um") else rng.uniform(-80, 80))
              for n in NAMES}
    m = {"machine_id": f"AC{seed}", "errors": errors,
         "play_arcsec": {"A": float(rng.uniform(3, 20)), "C": float(rng.uniform(3, 20))}}
    points = workpiece_points() if points is None else points
    top = np.linalg.norm(true_field(m, points), axis=1).max()
    m["errors"] = {n: v * field_max_um / top for n, v in errors.items()}
    return m


def probing(machine: dict, seed: int, noise_um: float = 0.8, a_deg=range(-30, 91, 15),
            c_deg=range(0, 331, 30), spheres=None, directions=(1, -1),
            started_at: str = "2026-03-02T08:00:00Z") -> pd.DataFrame:
    """The probing table: every sphere at every (A, C) from each direction, noisy centres."""
    rng = np.random.default_rng(seed)
    rows = []
    for name, q in (spheres or SPHERES).items():
        for a in a_deg:
            for c in c_deg:
                for d in directions:
                    p = place(machine, np.array(q), a, c, d) + rng.normal(0, noise_um * 1e-3, 3)
                    rows.append({"test_id": f"{machine['machine_id']}-t1",
                                 "machine_id": machine["machine_id"], "kinematics": "AC-table",
                                 "sphere": name, "sphere_x_mm": q[0], "sphere_y_mm": q[1],
                                 "sphere_z_mm": q[2], "a_deg": float(a), "c_deg": float(c),
                                 "direction": d, "x_mm": p[0], "y_mm": p[1], "z_mm": p[2],
                                 "started_at": started_at})
    return pd.DataFrame(rows)


FIELD_MAX_UM = (46.0, 55.0, 63.0, 72.0)


def fleet(noise_seed: int = 0) -> tuple[pd.DataFrame, list[dict]]:
    """Four A-C machines with their largest error over the workpiece points 46 to 72 um."""
    points = workpiece_points()
    machines = [machine(k, top, points) for k, top in enumerate(FIELD_MAX_UM)]
    frame = pd.concat([probing(m, seed=noise_seed * 10 + k) for k, m in enumerate(machines)],
                      ignore_index=True)
    return frame, machines
