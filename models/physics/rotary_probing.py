"""The five-axis twin's rotary table: a dual turntable (A-C or B-C) with seed 003's 12 geometric
errors, the play of each rotary axis and a touch probe that measures sphere centres.

The chain is composed of full homogeneous transforms (no linearisation, unlike the
identification in ``models.machine.kinematics``), seed 003 eq. 6 in data contract section 13's
frames:

    p = E_T R_T(t') E_C R_z(c') q,    E = Trans(delta) Rot(eps),

Rot(eps) the exact rotation by the vector eps (Rodrigues), T the tilting axis (A about X, B about
Y). Each axis reaches its commanded angle minus d b / 2, b its play [arcsec], d = +1 when the
angle was approached increasing: the play is taken up against the motion. The probe reads each
centre with independent Gaussian noise per coordinate. The twin writes the probing table of
data contract section 13 and its truth (``truth``), so the job can be checked against what was put
in. It stands beside the feed-drive twin (``models.physics.machine``), which it does not change.

>>> from models.physics import rotary_probing as rp
>>> frame = rp.probe(rp.paper_machine(), seed=0)                     # doctest: +SKIP

Units: mm, um (translations), urad (angles), arcsec (plays).

References
----------
.. [Wu2022] S. Wu et al. (seed 003): eq. 6, Table 1, Figures 11-12, Tables 4-5.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from features.probing import KINEMATICS, angle_column, axes_of, error_names, rotation

RAD_PER_ARCSEC = np.pi / (180.0 * 3600.0)
# Two spheres at different radius and height: the second separates the tilts of C from its
# shifts (one sphere, one height, confounds them).
SPHERES_MM = {"S1": (150.0, 0.0, 60.0), "S2": (-80.0, 110.0, 180.0)}
TILT_DEG = tuple(float(a) for a in range(-30, 91, 15))
C_DEG = tuple(float(c) for c in range(0, 331, 30))


@dataclass(frozen=True)
class RotaryMachine:
    """A dual-turntable machine's rotary axes.

    Attributes
    ----------
    machine_id : str
    kinematics : {"AC-table", "BC-table"}
    errors : dict
        Error name (``features.probing.error_names``) -> value [um or urad]; missing: 0.
    play_arcsec : dict
        Axis ("A"/"B", "C") -> play [arcsec].
    """

    machine_id: str = "T1"
    kinematics: str = "AC-table"
    errors: dict = field(default_factory=dict)
    play_arcsec: dict = field(default_factory=dict)

    def error(self, name: str) -> float:
        return float(self.errors.get(name, 0.0))

    def transform(self, axis: str) -> np.ndarray:
        """E of ``axis``, a 4 x 4 homogeneous transform: Trans(delta) Rot(eps)."""
        delta = np.array([self.error(f"delta_{t}_{axis}_um") for t in "xyz"]) * 1e-3  # mm
        eps = np.array([self.error(f"eps_{a}_{axis}_urad") for a in ("alpha", "beta", "gamma")
                        ]) * 1e-6
        m = np.eye(4)
        m[:3, :3] = _rodrigues(eps)
        m[:3, 3] = delta
        return m


def _rodrigues(vector: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(vector))
    if angle == 0:
        return np.eye(3)
    k = vector / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def centres_mm(machine: RotaryMachine, point_mm, tilt_deg, c_deg, direction) -> np.ndarray:
    """Where the table puts each point q [mm] at the commanded angles, approached from
    ``direction`` (+1 / -1): exact chain, shape (n, 3)."""
    tilt, table = axes_of(machine.kinematics)
    _, k, _ = KINEMATICS[machine.kinematics]
    d = np.asarray(direction, float)
    t = np.radians(np.asarray(tilt_deg, float)) - d * machine.play_arcsec.get(tilt, 0.0) / 2 \
        * RAD_PER_ARCSEC
    c = np.radians(np.asarray(c_deg, float)) - d * machine.play_arcsec.get(table, 0.0) / 2 \
        * RAD_PER_ARCSEC
    e_t, e_c = machine.transform(tilt), machine.transform(table)
    q = np.c_[np.asarray(point_mm, float).reshape(-1, 3), np.ones(len(t))]
    r_t, r_c = np.zeros((len(t), 4, 4)), np.zeros((len(t), 4, 4))
    r_t[:, :3, :3], r_c[:, :3, :3] = rotation(k, t), rotation(2, c)
    r_t[:, 3, 3] = r_c[:, 3, 3] = 1.0
    chain = np.einsum("ij,njk,kl,nlm->nim", e_t, r_t, e_c, r_c)
    return np.einsum("nij,nj->ni", chain, q)[:, :3]


def probe(machine: RotaryMachine, *, spheres: dict | None = None, tilt_deg=TILT_DEG,
          c_deg=C_DEG, directions=(1, -1), noise_um: float = 0.8, seed: int = 0,
          test_id: str | None = None, started_at: str | None = None) -> pd.DataFrame:
    """A probing cycle on the twin: every sphere at every pair of angles from each direction.

    Parameters
    ----------
    machine : RotaryMachine
    spheres : dict, optional
        Sphere name -> its centre (x, y, z) in the table frame [mm]; default ``SPHERES_MM``.
    tilt_deg, c_deg : sequence of float
        Commanded angles of the tilting axis and of C [deg].
    directions : sequence of int
        Approach directions run (+1, -1).
    noise_um : float
        Standard deviation of the probe per coordinate [um].
    seed : int
        Random seed of the noise.
    test_id, started_at : str, optional
        The run's id (default ``<machine>-probe``) and ISO start time (a column when given).

    Returns
    -------
    DataFrame
        The probing table of data contract section 13.
    """
    spheres = SPHERES_MM if spheres is None else spheres
    tilt, _ = axes_of(machine.kinematics)
    s, t, c, d = (a.ravel() for a in np.meshgrid(np.arange(len(spheres)), tilt_deg, c_deg,
                                                 directions, indexing="ij"))
    s = s.astype(int)
    q = np.array(list(spheres.values()), float)[s]
    rng = np.random.default_rng(seed)
    measured = centres_mm(machine, q, t, c, d) + rng.normal(0.0, noise_um * 1e-3, (len(t), 3))
    frame = pd.DataFrame({
        "test_id": test_id or f"{machine.machine_id}-probe", "machine_id": machine.machine_id,
        "kinematics": machine.kinematics, "sphere": np.array(list(spheres))[s],
        "sphere_x_mm": q[:, 0], "sphere_y_mm": q[:, 1], "sphere_z_mm": q[:, 2],
        angle_column(tilt): t.astype(float), "c_deg": c.astype(float),
        "direction": d.astype(int), "x_mm": measured[:, 0], "y_mm": measured[:, 1],
        "z_mm": measured[:, 2]})
    if started_at is not None:
        frame["started_at"] = started_at
    return frame


def truth(machine: RotaryMachine) -> dict:
    """What was put in, as the job reports it: every error, the plays [arcsec]."""
    tilt, table = axes_of(machine.kinematics)
    return {"machine_id": machine.machine_id, "kinematics": machine.kinematics,
            "errors": {n: machine.error(n) for n in error_names(machine.kinematics)},
            "play_arcsec": {tilt: float(machine.play_arcsec.get(tilt, 0.0)),
                            table: float(machine.play_arcsec.get(table, 0.0))}}


def paper_machine(machine_id: str = "W1") -> RotaryMachine:
    """An A-C machine with errors of seed 003's magnitude: a comprehensive error of about
    0.12 mm at the edge of a 200 mm workpiece at A = C = 0, growing towards 0.2 mm as A
    turns (its Tables 4-5), a few um at the centre. Seed 003 gives the field, not the 12 errors
    themselves: these are chosen to reproduce its size, not its values."""
    return RotaryMachine(machine_id, "AC-table", errors={
        "delta_x_A_um": 1.5, "delta_y_A_um": -2.0, "delta_z_A_um": 1.0,
        "eps_alpha_A_urad": 170.0, "eps_beta_A_urad": 200.0, "eps_gamma_A_urad": -130.0,
        "delta_x_C_um": 1.0, "delta_y_C_um": 1.5, "delta_z_C_um": -1.0,
        "eps_alpha_C_urad": 145.0, "eps_beta_C_urad": -330.0, "eps_gamma_C_urad": 230.0},
        play_arcsec={"A": 12.0, "C": 8.0})


def random_machine(seed: int, kinematics: str = "AC-table", angle_urad: float = 60.0,
                   shift_um: float = 10.0, play_arcsec: float = 15.0) -> RotaryMachine:
    """A machine with random errors: translations uniform in +-``shift_um``, angles in
    +-``angle_urad``, plays uniform in [0, ``play_arcsec``]."""
    rng = np.random.default_rng(seed)
    tilt, table = axes_of(kinematics)
    errors = {n: float(rng.uniform(-shift_um, shift_um) if n.endswith("_um") else
                       rng.uniform(-angle_urad, angle_urad)) for n in error_names(kinematics)}
    return RotaryMachine(f"R{seed}", kinematics, errors,
                         {tilt: float(rng.uniform(0, play_arcsec)),
                          table: float(rng.uniform(0, play_arcsec))})


def write_run(out, machines: list[RotaryMachine], seed: int = 0, **probing) -> dict[str, Path]:
    """``probes.csv`` (the probing table of every machine) and ``truth.json`` (``truth`` of
    each) under ``out``."""
    from features.readings.fileio import atomic_path, write_json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frame = pd.concat([probe(m, seed=seed + i, **probing) for i, m in enumerate(machines)],
                      ignore_index=True)
    with atomic_path(out / "probes.csv") as tmp:
        frame.to_csv(tmp, index=False)
    truth_path = write_json(out / "truth.json", {"machines": [truth(m) for m in machines]})
    return {"probes": out / "probes.csv", "truth": truth_path}
