"""The 12 geometric errors of a dual-turntable five-axis machine's rotary axes and their play,
identified from probed calibration spheres; the error field they make over the workspace.

Model (seed 003 eq. 6, data contract section 13). A point q fixed on the table (table frame, mm)
appears in machine coordinates at

    p = E_T R_T(t) E_C R_z(c) q,

T the tilting axis (A about X, or B about Y), C the table axis, E the small-error transforms of
seed 003 Table 1: E = [[1, -eps_gamma, eps_beta, delta_x], [eps_gamma, 1, -eps_alpha, delta_y],
[-eps_beta, eps_alpha, 1, delta_z]], i.e. E v = v + eps x v + delta. To first order in the
errors, with p0 = R_T(t) R_z(c) q where the ideal machine puts the point,

    dp = delta_T + eps_T x p0 + R_T(t) delta_C + (R_T(t) eps_C) x p0
         - (d / 2) [b_T (e_T x p0) + b_C ((R_T(t) e_z) x p0)],                      (1)

the last line the play: an axis reaches its commanded angle minus d b / 2, d = +1 when the
angle was approached increasing (the play b is taken up against the motion), so
``direction`` separates b from a zero offset. Eq. (1) is linear in the 12 errors and 2 plays,
dp = J theta, and a probing cycle stacks it for every probed centre.

Identification is least squares on J with its columns scaled to unit length, solved through
the SVD: singular values below ``RTOL`` times the largest span the null space, the directions
of theta the probing cannot see. Structurally, R_A(a) leaves e_x unchanged, so a shift along X of
the A axis and of the C axis (``delta_x_A_um``, ``delta_x_C_um``) move every probed point alike,
and so do the two rotations about X (``eps_alpha_A_urad``, ``eps_alpha_C_urad``); for B-C, the
shifts along Y and the rotations about Y. Errors in a null-space direction are reported as
None with their group and the combinations of the group the data determine (for a pair, the
sum), never an arbitrary split. Standard uncertainties are from the residual variance
s^2 = RSS / (3n - rank) and the pseudo-inverse: cov(theta) = s^2 (J^T J)^+, exact for every
identifiable error and combination (they do not depend on the null space).

The field (seed 003 eq. 12-13) is dp of eq. (1) without the play (a point has no approach
direction: the mean of both), E = |dp|.

Units: positions mm, translations and field um, angles urad, plays arcsec.

References
----------
.. [Wu2022] S. Wu, Z. Dong, F. Qi, Z. Fan (seed 003), "Prediction of the Comprehensive Error
   Field in the Machining Space of the Five-Axis Machine Tool Based on the S-Shaped Specimen
   Family": eq. 1 (rotations), eq. 6 (error chain), Table 1 (the 12 errors), eq. 12-13 (field).
.. ISO 10791-6 (five-axis accuracy, probing of spheres); ISO 230-7 (rotary axes).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from features.probing import KINEMATICS, axes_of, error_names, rotation

# Singular values below RTOL x the largest are taken as zero: the combination's uncertainty
# would be a million times the best-determined one's, i.e. the data do not determine it.
RTOL = 1e-6
# A parameter belongs to an inseparable group when its share of the null space exceeds this.
NULL_SHARE = 1e-6
UM_PER_MM = 1e3
UM_PER_URAD_MM = 1e-3  # urad x mm -> um
RAD_PER_ARCSEC = np.pi / (180.0 * 3600.0)
MIN_ANGLES = 3        # a constant, cos t and sin t need three distinct angles
MIN_SPAN_DEG = 30.0   # ... apart enough that they are not nearly proportional


def play_names(kinematics: str) -> tuple[str, str]:
    tilt, table = axes_of(kinematics)
    return f"play_{tilt}_arcsec", f"play_{table}_arcsec"


def parameter_names(kinematics: str) -> tuple[str, ...]:
    """The 12 errors (``features.probing.error_names``) and the 2 plays, J's columns."""
    return (*error_names(kinematics), *play_names(kinematics))


def _cross_columns(p0_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(axis_k x p0) for each row, axes shape (n, 3, 3) holding the axis vectors as columns;
    returns (n, 3, 3): [row, component, k]."""
    return np.cross(np.moveaxis(axes, 2, 1), p0_mm[:, None, :]).transpose(0, 2, 1)


def design_matrix(kinematics: str, point_mm, tilt_deg, c_deg, direction=None) -> np.ndarray:
    """J of eq. (1): the change of each probed centre [um] per unit of each parameter.

    Parameters
    ----------
    kinematics : {"AC-table", "BC-table"}
    point_mm : array-like, shape (n, 3)
        The points in the table frame at T = C = 0 [mm].
    tilt_deg, c_deg : array-like, shape (n,)
        Commanded angles of the tilting axis (A or B) and of C [deg].
    direction : array-like, shape (n,), optional
        +1 / -1 approach direction; None: no play columns (the field).

    Returns
    -------
    ndarray, shape (3 n, 12) or (3 n, 14)
        Rows x, y, z of each point in turn [um]; columns in ``parameter_names`` order
        (translations per um, angles per urad, plays per arcsec).
    """
    _, k, _ = KINEMATICS[kinematics]
    q = np.asarray(point_mm, float).reshape(-1, 3)
    r_t = rotation(k, np.radians(np.asarray(tilt_deg, float)))
    r_c = rotation(2, np.radians(np.asarray(c_deg, float)))
    p0 = np.einsum("nij,njk,nk->ni", r_t, r_c, q)
    n = len(q)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    blocks = [eye,                                              # delta_T
              _cross_columns(p0, eye) * UM_PER_URAD_MM,         # eps_T x p0
              r_t,                                              # R_T delta_C
              _cross_columns(p0, r_t) * UM_PER_URAD_MM]         # (R_T eps_C) x p0
    if direction is not None:
        d = np.asarray(direction, float)[:, None]
        scale = -0.5 * d * RAD_PER_ARCSEC * UM_PER_MM
        turn_t = np.cross(np.eye(3)[k], p0) * scale             # e_T x p0
        turn_c = np.cross(r_t[:, :, 2], p0) * scale             # (R_T e_z) x p0
        blocks.append(np.stack([turn_t, turn_c], axis=2))
    return np.concatenate(blocks, axis=2).reshape(3 * n, -1)


@dataclass
class Identification:
    """The parameters of one machine identified from its probed centres.

    Attributes
    ----------
    kinematics : str
    names : tuple of str
        ``parameter_names(kinematics)``.
    theta : ndarray
        Minimum-norm least-squares solution (scaled columns) in ``names`` order: its entries
        in ``not_identifiable`` groups are a convention, never reported as values.
    cov : ndarray
        Its covariance s^2 (J^T J)^+.
    groups : list of list of str
        The parameters the probing cannot separate, one list per inseparable group.
    combinations : list of dict
        Per group, the combinations it does determine: ``names``, ``coefficients``,
        ``label`` (``"delta_x_A_um + delta_x_C_um"``), ``value``, ``u``.
    residual_rms_um : float
        RMS of the residual coordinates [um].
    rank : int
    points : int
        Probed centres used.
    scale : ndarray
        Column lengths of J (the SVD ran on J / scale).
    null : ndarray
        Null-space basis (scaled coordinates), shape (p, p - rank).
    """

    kinematics: str
    names: tuple
    theta: np.ndarray
    cov: np.ndarray
    groups: list
    combinations: list
    residual_rms_um: float
    rank: int
    points: int
    scale: np.ndarray
    null: np.ndarray = field(repr=False, default=None)

    @property
    def hidden(self) -> set:
        return {name for group in self.groups for name in group}

    def value(self, name: str):
        """The parameter's estimate, None when it lies in an inseparable group."""
        return None if name in self.hidden else float(self.theta[self.names.index(name)])

    def u(self, name: str):
        """Its standard uncertainty (k = 1), None when inseparable."""
        if name in self.hidden:
            return None
        i = self.names.index(name)
        return float(np.sqrt(max(self.cov[i, i], 0.0)))


def identify(kinematics: str, point_mm, tilt_deg, c_deg, direction, deviation_um,
             rtol: float = RTOL) -> Identification:
    """Identify the 12 errors and 2 plays by linear least squares on eq. (1).

    Parameters
    ----------
    kinematics : {"AC-table", "BC-table"}
    point_mm : array-like, shape (n, 3)
        Sphere centres in the table frame [mm].
    tilt_deg, c_deg, direction : array-like, shape (n,)
        Commanded angles [deg] and approach direction (+1 / -1).
    deviation_um : array-like, shape (n, 3)
        Measured minus nominal centre, machine coordinates [um].
    rtol : float
        Relative singular-value tolerance of the rank.

    Returns
    -------
    Identification
    """
    jac = design_matrix(kinematics, point_mm, tilt_deg, c_deg, direction)
    y = np.asarray(deviation_um, float).reshape(-1)
    scale = np.linalg.norm(jac, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    # The SVD through the Gram matrix of the scaled columns (p x p, p = 14): its eigenvectors
    # are J's right singular vectors, its eigenvalues their squares. With unit columns the
    # exact null directions sit at ~1e-16 and RTOL^2 = 1e-12 stays far above rounding, while
    # a tall SVD of J costs a thousand times more.
    scaled = jac / scale
    eig, v = np.linalg.eigh(scaled.T @ scaled)
    order = np.argsort(eig)[::-1]
    s, vt = np.sqrt(np.clip(eig[order], 0.0, None)), v[:, order].T
    rank = int(np.sum(s > rtol * s[0]))
    v_r, s_r = vt[:rank].T, s[:rank]
    theta_n = v_r @ ((v_r.T @ (scaled.T @ y)) / s_r ** 2)
    theta = theta_n / scale
    resid = y - jac @ theta
    dof = max(len(y) - rank, 1)
    s2 = float(resid @ resid) / dof
    cov = s2 * (v_r / s_r ** 2) @ v_r.T / np.outer(scale, scale)
    null = vt[rank:].T
    names = parameter_names(kinematics)
    groups = _groups(null, names)
    combos = [_combination(g, names, null, scale, theta, cov) for g in groups]
    return Identification(kinematics, names, theta, cov, groups,
                          [c for combo in combos for c in combo],
                          float(np.sqrt(np.mean(resid ** 2))), rank, len(y) // 3, scale, null)


def _groups(null: np.ndarray, names) -> list[list[str]]:
    """Inseparable groups: connected components of the null-space projector P = N N^T (basis
    independent: two independent degeneracies stay two groups)."""
    if null.shape[1] == 0:
        return []
    proj = null @ null.T
    inside = np.flatnonzero(np.diag(proj) > NULL_SHARE)
    groups, seen = [], set()
    for i in inside:
        if i in seen:
            continue
        stack, group = [i], set()
        while stack:
            j = stack.pop()
            if j in group:
                continue
            group.add(j)
            stack += [k for k in inside if abs(proj[j, k]) > NULL_SHARE and k not in group]
        seen |= group
        groups.append([names[j] for j in sorted(group)])
    return groups


def _combination(group, names, null, scale, theta, cov) -> list[dict]:
    """The combinations c . theta of a group's parameters the data determine (c orthogonal
    to the null space in scaled coordinates), each with its value and standard uncertainty;
    coefficients scaled so the largest is 1 (a pair: the sum, or the difference)."""
    idx = [names.index(n) for n in group]
    n_g = null[idx]
    _, s, vt = np.linalg.svd(n_g.T, full_matrices=True)
    kept = int(np.sum(s > NULL_SHARE))
    out = []
    for c_n in vt[kept:]:
        coef = c_n * scale[idx]
        coef = coef / coef[np.argmax(np.abs(coef))]
        coef = np.where(np.abs(coef - np.round(coef)) < 1e-6, np.round(coef), coef)
        full = np.zeros(len(names))
        full[idx] = coef
        terms = [(c, n) for c, n in zip(coef, group) if abs(c) > 1e-9]
        label = " ".join(f"{'-' if c < 0 else '+'} {'' if abs(c) == 1 else f'{abs(c):.4g} '}{n}"
                         for c, n in terms).removeprefix("+ ")
        out.append({"names": [n for _, n in terms], "coefficients": [float(c) for c, _ in terms],
                    "label": label, "value": float(full @ theta),
                    "u": float(np.sqrt(max(full @ cov @ full, 0.0)))})
    return out


def field_um(ident: Identification, point_mm, tilt_deg, c_deg) -> tuple[np.ndarray, ...]:
    """The geometric error field (seed 003 eq. 12-13): where each point is minus where it
    should be, machine coordinates [um], with its standard uncertainty.

    Parameters
    ----------
    ident : Identification
    point_mm : array-like, shape (n, 3)
        Workpiece points in the table frame [mm].
    tilt_deg, c_deg : array-like, shape (n,)
        Angles [deg].

    Returns
    -------
    dp_um : ndarray, shape (n, 3)
        NaN where the probing does not determine the point's error (a direction of the null
        space reaches it).
    u_um : ndarray, shape (n, 3)
        Standard uncertainty of each component (k = 1).
    error_um : ndarray, shape (n,)
        |dp| (eq. 13).
    """
    jac = design_matrix(ident.kinematics, point_mm, tilt_deg, c_deg)
    p = jac.shape[1]
    theta, cov = ident.theta[:p], ident.cov[:p, :p]
    dp = (jac @ theta).reshape(-1, 3)
    u = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0)).reshape(-1, 3)
    if ident.null.shape[1]:
        scaled = jac / ident.scale[:p]
        reach = np.linalg.norm(scaled @ ident.null[:p], axis=1)
        blind = (reach > 1e-6 * np.maximum(np.linalg.norm(scaled, axis=1), 1e-300)).reshape(
            -1, 3).any(axis=1)
        dp[blind], u[blind] = np.nan, np.nan
    return dp, u, np.linalg.norm(dp, axis=1)


@functools.cache
def structural_groups(kinematics: str) -> tuple[tuple[str, ...], ...]:
    """The groups no probing of spheres separates: those of a generic cycle (two spheres off
    the C axis at different heights, many angles, both directions). For A-C: the shifts
    along X and the rotations about X of A and C; for B-C, along and about Y."""
    t, c = np.meshgrid(np.linspace(-30, 90, 7), np.linspace(0, 300, 6), indexing="ij")
    t, c = np.r_[t.ravel(), t.ravel()], np.r_[c.ravel(), c.ravel()]
    q = np.r_[np.tile([[150.0, 20.0, 60.0]], (len(t) // 2, 1)),
              np.tile([[-70.0, 110.0, 170.0]], (len(t) // 2, 1))]
    d = np.where(np.arange(len(t)) % 2, 1.0, -1.0)
    y = np.zeros(3 * len(t))
    ident = identify(kinematics, np.r_[q, q], np.r_[t, t], np.r_[c, c], np.r_[d, -d],
                     np.r_[y, y])
    return tuple(tuple(g) for g in ident.groups)


def span_problem(tilt_deg, c_deg, tilt: str) -> str | None:
    """Why the angles cannot separate the errors, or None: each axis needs ``MIN_ANGLES``
    distinct angles spanning ``MIN_SPAN_DEG`` (the errors enter as a constant, cos and sin of
    each angle)."""
    for axis, angles in ((tilt, tilt_deg), ("C", c_deg)):
        distinct = np.unique(np.round(np.asarray(angles, float), 6))
        span = float(distinct[-1] - distinct[0])
        if len(distinct) < MIN_ANGLES or span < MIN_SPAN_DEG:
            shown = ", ".join(f"{a:g}" for a in distinct[:6]) + (" ..." if len(distinct) > 6
                                                                 else "")
            return (f"probed at {len(distinct)} {axis} angle(s) ({shown} deg) spanning "
                    f"{span:g} deg: the {axis} axis's errors need at least {MIN_ANGLES} "
                    f"{axis} angles spanning {MIN_SPAN_DEG:g} deg or more")
    return None


def workspace_grid(half_width_mm: float, n: int = 9) -> np.ndarray:
    """Points of the workpiece cube, x, y in [-w, w], z in [0, w] [mm], n per side; shape
    (n^3, 3)."""
    xy = np.linspace(-half_width_mm, half_width_mm, n)
    z = np.linspace(0.0, half_width_mm, n)
    return np.stack(np.meshgrid(xy, xy, z, indexing="ij"), axis=-1).reshape(-1, 3)


def extremes(ident: Identification, grid_mm, tilt_deg, c_deg) -> dict:
    """Smallest and largest comprehensive error over ``grid_mm`` at one pair of angles [um]
    (seed 003 Tables 4-5: Delta E min and max)."""
    n = len(grid_mm)
    _, _, e = field_um(ident, grid_mm, np.full(n, tilt_deg), np.full(n, c_deg))
    if np.isnan(e).all():
        return {"min_um": None, "max_um": None}
    return {"min_um": float(np.nanmin(e)), "max_um": float(np.nanmax(e))}
