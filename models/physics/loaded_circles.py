"""The machine twin under quasi-static load: position-dependent stiffness and loaded
double-ballbar (LDBB) circles with their truth.

The twin of ``models.physics.machine`` is extended by composition: a ``Stiffness`` record
states the compliance of the structural loop between tool and workpiece as a function of
where the machine stands, and ``loaded_circle_test`` adds the deflection a loaded ballbar
causes to the twin's own circular test (geometry, play, friction spike and servo lag unchanged).

The loop's compliance at machine position p = (x, y, z) [um/N], a symmetric 3 x 3 matrix:

.. math:: C(p) = C_{column} + \\frac{y - y_0}{1000} G_{saddle}
          + \\left(\\frac{e}{e_{ref}}\\right)^3 C_{ram}, \\qquad e = z_{top} - z

- the column and the spindle head (constant, with a cross term: the column leans under a
  force along X a little towards Y);
- the saddle's guideways, more compliant the further the saddle travels from the column
  (linear in y);
- the ram, a cantilever extended by e below its top: its lateral compliance grows with the
  cube of its extension (Euler-Bernoulli, :math:`\\delta = F L^3 / 3EI`).

A loaded ballbar pushes spindle and table apart with F along the bar (> 0: outward); the loop
yields by :math:`C F u` and the bar reads its radial part :math:`F u^T C u` on top of the
unloaded circle [Archenti2012]_.

References
----------
.. [Archenti2012] A. Archenti et al., "A new method for circular testing of machine tools under
   loaded condition", Procedia CIRP 1 (2012) 575-580.
.. [Szipka2015] K. Szipka, "Prediction of the machine tool errors under quasi-static load",
   KTH 2015 (seed 002).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from models.physics import machine as twin

LDBB_COLUMNS = (*twin.CIRCLE_COLUMNS, "load_n", "centre_x_mm", "centre_y_mm", "centre_z_mm")


@dataclass(frozen=True)
class Stiffness:
    """The structural loop's compliance over the workspace.

    Attributes
    ----------
    column_um_per_n : ndarray, shape (3, 3)
        Column and spindle head, the same everywhere [um/N].
    saddle_um_per_n_per_m : ndarray, shape (3, 3)
        Added per metre of y above ``y0_mm`` [um/N/m].
    ram_um_per_n : ndarray, shape (3, 3)
        The ram's compliance at extension ``extension_ref_mm`` [um/N]; it scales with the cube
        of the extension.
    ram_top_mm : float
        z at which the ram's extension is zero [mm].
    extension_ref_mm : float
        The extension at which ``ram_um_per_n`` holds [mm].
    y0_mm : float
        y of the saddle nearest the column [mm].
    """

    column_um_per_n: np.ndarray
    saddle_um_per_n_per_m: np.ndarray
    ram_um_per_n: np.ndarray
    ram_top_mm: float
    extension_ref_mm: float = 1000.0
    y0_mm: float = 0.0

    def compliance_um_per_n(self, position_mm) -> np.ndarray:
        """C(p) at the positions (n, 3) [mm], shape (n, 3, 3) [um/N]."""
        p = np.atleast_2d(np.asarray(position_mm, float))
        extension = np.clip(self.ram_top_mm - p[:, 2], 0.0, None)
        ram = (extension / self.extension_ref_mm) ** 3
        saddle = (p[:, 1] - self.y0_mm) / 1000.0
        return (self.column_um_per_n[None] + saddle[:, None, None] * self.saddle_um_per_n_per_m
                + ram[:, None, None] * self.ram_um_per_n[None])

    def deflection_um(self, position_mm, force_n) -> np.ndarray:
        """C(p) F at the positions (n, 3) [mm] for forces (n, 3) [N], shape (n, 3) [um]."""
        f = np.atleast_2d(np.asarray(force_n, float))
        return np.einsum("nij,nj->ni", self.compliance_um_per_n(position_mm), f)


def paper_stiffness(machine: twin.Machine | None = None) -> Stiffness:
    """Stiffness of plausible size for the paper's machine (seed 002 gives none the copy
    shows): 40-60 N/um near the ram's top, 10-15 N/um at its full extension, Z stiffer."""
    travel = (machine.geometry.travel_mm if machine is not None else twin.PAPER_TRAVEL_MM)
    column = np.array([[0.016, 0.003, 0.0], [0.003, 0.020, 0.0], [0.0, 0.0, 0.008]])
    saddle = np.array([[0.002, 0.0, 0.0], [0.0, 0.004, 0.0], [0.0, 0.0, 0.0]])
    ram = np.array([[0.060, 0.004, 0.0], [0.004, 0.050, 0.0], [0.0, 0.0, 0.004]])
    return Stiffness(column, saddle, ram, ram_top_mm=float(travel["Z"][1]),
                     extension_ref_mm=1000.0, y0_mm=float(travel["Y"][0]))


def loaded_circle_test(machine: twin.Machine, stiffness: Stiffness, *, center_mm,
                       load_n: float, plane: str = "XY", direction: str = "CCW",
                       radius_mm: float = 150.0, feed_mm_min: float = 1000.0,
                       points: int = 360, test_id: str | None = None,
                       unloaded: pd.DataFrame | None = None) -> pd.DataFrame:
    """One LDBB run: the twin's circular test (``machine.circle_test``) plus the radial part of
    the deflection under the bar's force, :math:`F u^T C(p) u`, C at the tool's place p.

    ``unloaded``: the same circle's ``circle_test`` when already run (the load does not change
    it, so a campaign runs it once per centre and direction).

    Returns
    -------
    DataFrame
        data contract section 12's columns (``LDBB_COLUMNS``): the circle table of section 11,
        ``load_n`` and the centre.
    """
    center = np.asarray(center_mm, float)
    frame = (twin.circle_test(machine, plane=plane, radius_mm=radius_mm,
                              feed_mm_min=feed_mm_min, direction=direction, center_mm=center,
                              points=points) if unloaded is None else unloaded).copy()
    if test_id is not None:
        frame["test_id"] = test_id
    first, second = twin.PLANES[plane]
    t = np.radians(frame["angle_deg"].to_numpy())
    u = np.zeros((len(t), 3))
    u[:, first], u[:, second] = np.cos(t), np.sin(t)
    c = stiffness.compliance_um_per_n(center + radius_mm * u)
    frame["deviation_um"] += load_n * np.einsum("ni,nij,nj->n", u, c, u)
    return frame.assign(load_n=float(load_n), centre_x_mm=center[0], centre_y_mm=center[1],
                        centre_z_mm=center[2])[list(LDBB_COLUMNS)]


def centre_grid(machine: twin.Machine, per_axis: int = 3, margin: float = 0.2) -> np.ndarray:
    """Centres on a per_axis^3 grid across the travel, ``margin`` of each travel kept clear
    (room for the circle), shape (per_axis^3, 3) [mm]."""
    axes = []
    for axis in twin.AXES:
        lo, hi = machine.geometry.travel_mm[axis]
        span = hi - lo
        axes.append(np.linspace(lo + margin * span, hi - margin * span, per_axis))
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T


def ldbb_campaign(machine: twin.Machine, stiffness: Stiffness, centres_mm, *,
                  loads_n=(100.0, 300.0, 500.0), plane: str = "XY",
                  directions=("CCW", "CW"), radius_mm: float = 150.0,
                  feed_mm_min: float = 1000.0, points: int = 360, noise_um: float = 0.2,
                  seed: int = 0) -> tuple[pd.DataFrame, dict]:
    """LDBB circles at every centre and load, in each direction, with reading noise.

    Returns
    -------
    DataFrame, dict
        The table (data contract section 12) and the truth: ``centres`` (per centre its
        ``centre_mm``, ``compliance_um_per_n`` (3 x 3 at the centre) and
        ``stiffness_n_per_um`` by axis, 1 / c_ii), ``ram_top_mm``, ``noise_um``.
    """
    rng = np.random.default_rng(seed)
    frames, truth = [], []
    for k, centre in enumerate(np.atleast_2d(np.asarray(centres_mm, float))):
        for direction in directions:
            unloaded = twin.circle_test(machine, plane=plane, radius_mm=radius_mm,
                                        feed_mm_min=feed_mm_min, direction=direction,
                                        center_mm=centre, points=points)
            for load in loads_n:
                test = f"{machine.machine_id}-c{k:02d}-{load:g}N-{direction}"
                run = loaded_circle_test(machine, stiffness, center_mm=centre, load_n=load,
                                         plane=plane, direction=direction, radius_mm=radius_mm,
                                         test_id=test, unloaded=unloaded)
                run["deviation_um"] += rng.normal(0.0, noise_um, len(run))
                frames.append(run)
        c = stiffness.compliance_um_per_n(centre)[0]
        truth.append({"centre_mm": [float(v) for v in centre],
                      "compliance_um_per_n": c.tolist(),
                      "stiffness_n_per_um": {a: float(1.0 / c[i, i])
                                             for i, a in enumerate(twin.AXES)}})
    return (pd.concat(frames, ignore_index=True),
            {"centres": truth, "ram_top_mm": stiffness.ram_top_mm, "noise_um": noise_um})
