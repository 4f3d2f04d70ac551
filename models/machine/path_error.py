"""The error of the tool along a path under quasi-static load, in three parts, each from the
model a test of the machine gave (seed 002's synthesis of bottom-up and top-down models):

- **geometric**: the 21 geometric errors identified from laser tests
  (``models.machine.volumetric``), :math:`E(P, h)` at the tool point (``models.physics.machine
  .tool_error_um``);
- **backlash**: each axis trails its command by half its play in the direction it last moved,
  :math:`e_a = -s_a b_a / 2`, the play :math:`b_a` from the ballbar circles' diagnosis
  (``models.machine.circle``), the direction :math:`s_a` from the path (held through stops; before the
  axis first moves, the direction of its first move, as if the path were approached that way);
- **load**: the deflection :math:`C(p) F` under the path's force, C from the stiffness map of
  loaded circles (``models.machine.stiffness``).

The parts add to first order: each is microns on a path of millimetres.

References
----------
.. [Szipka2015] K. Szipka, "Prediction of the machine tool errors under quasi-static load",
   KTH 2015 (seed 002): the geometric model (bottom-up, laser) and the stiffness (top-down,
   LDBB) combined into the error under quasi-static load along a tool path.
"""

from __future__ import annotations

import numpy as np

AXES = ("X", "Y", "Z")


def motion_sense(path_mm) -> np.ndarray:
    """The direction each axis last moved at each point of the path (n, 3): +1 or -1, held
    through stops; before an axis first moves, the direction of its first move (0 if it never
    moves)."""
    p = np.atleast_2d(np.asarray(path_mm, float))
    step = np.sign(np.diff(p, axis=0, prepend=p[:1]))
    out = np.zeros_like(step)
    for j in range(p.shape[1]):
        moving = np.flatnonzero(step[:, j])
        if moving.size == 0:
            continue
        last = np.maximum.accumulate(np.where(step[:, j] != 0, np.arange(len(p)), -1))
        out[:, j] = np.where(last >= 0, step[np.maximum(last, 0), j], step[moving[0], j])
    return out


def backlash_error_um(path_mm, play_um: dict) -> np.ndarray:
    """Lost motion along the path [um], (n, 3): :math:`-s_a b_a / 2` per axis, ``play_um``
    axis -> b [um] (an axis without a play: 0)."""
    sense = motion_sense(path_mm)
    b = np.array([play_um.get(a, 0.0) for a in AXES])
    return -sense * b / 2.0


def combined_play_um(estimates) -> tuple[dict, dict]:
    """Each axis's play from several circles, weighted by 1/u^2.

    Parameters
    ----------
    estimates : iterable of (axis, play [um], standard uncertainty [um])

    Returns
    -------
    dict, dict
        Axis -> play [um] and axis -> its standard uncertainty [um].
    """
    sums = {}
    for axis, value, u in estimates:
        if not (np.isfinite(value) and np.isfinite(u) and u > 0):
            continue
        w = 1.0 / u ** 2
        total = sums.setdefault(axis, [0.0, 0.0])
        total[0] += w * value
        total[1] += w
    return ({a: s[0] / s[1] for a, s in sums.items()},
            {a: float(np.sqrt(1.0 / s[1])) for a, s in sums.items()})
