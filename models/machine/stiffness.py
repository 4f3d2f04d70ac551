"""Static stiffness across the workspace from loaded double-ballbar (LDBB) circles.

A loaded ballbar pushes the spindle and the table apart with a force F along the bar while
two axes move round a circle [Archenti2012]_. At the angle :math:`\\theta` of a plane with
axes (a, b) the bar's direction is :math:`u = (\\cos\\theta, \\sin\\theta)`; the structural
loop yields by :math:`\\delta = F\\,C\\,u` (C the plane's 2 x 2 compliance, um/N), and the
bar reads its radial part:

.. math:: \\Delta r(\\theta, F) = g_d(\\theta) + F\\,u^T C u, \\qquad
          u^T C u = \\tfrac{c_{aa} + c_{bb}}{2} + \\tfrac{c_{aa} - c_{bb}}{2}\\cos 2\\theta
          + c_{ab}\\sin 2\\theta

:math:`g_d` is everything the load does not change: the geometric errors, the backlash step
and reversal spike, the servo lag (all per direction d of travel, CW or CCW). It is not
modelled: at each angle of each direction the deviations of the runs at different loads are
regressed on the load (``load_slopes``), which leaves :math:`g_d` in the intercept whatever its
shape, and the slope :math:`s(\\theta) = u^T C u` is fitted by its Fourier terms
(``plane_compliance``): the constant, :math:`\\cos 2\\theta` and :math:`\\sin 2\\theta` give
:math:`c_{aa}, c_{bb}, c_{ab}`; :math:`\\cos\\theta, \\sin\\theta` of each direction absorb a load-correlated
shift of the centre (the compliance changing across the circle, the pivot moved between runs)
and are not reported.

Stiffness in a direction is the force along it per um of deflection along it under that
force: :math:`k_a = 1 / c_{aa}` [N/um].

The stiffness map (``fit_map``) states each compliance component over the workspace as a
linear model in position, the form chosen by leave-one-centre-out cross-validation
(``choose_map``) among ``FORMS``: ``constant``; ``linear`` in x, y, z; ``quadratic`` in the
ram's travel z; ``cubic``: a cantilever ram, whose lateral compliance grows with the cube of
its extension e (:math:`\\delta = F L^3 / 3EI`, Euler-Bernoulli), :math:`c = c_0 + c_x x +
c_y y + c_3 e^3`, e = ``ram_top_mm`` - z (the ram extends downward from its top).

Units: positions mm, forces N, compliances um/N, stiffnesses N/um, deflections um.

References
----------
.. [Archenti2012] A. Archenti, M. Nicolescu, G. Casterman, S. Hjelm, "A new method for circular
   testing of machine tools under loaded condition", 5th CIRP Conference on High Performance
   Cutting, Procedia CIRP 1 (2012) 575-580.
.. [Szipka2015] K. Szipka, "Prediction of the machine tool errors under quasi-static load",
   master thesis, KTH Stockholm, 2015 (seed 002): stiffness across the workspace from LDBB
   circles (top-down) combined with the geometric errors (bottom-up).
.. [Hastie2009] T. Hastie, R. Tibshirani, J. Friedman, The Elements of Statistical Learning,
   2nd ed., Springer 2009, section 7.10 (cross-validation, the one-standard-error rule).
.. [Birge1932] R. T. Birge, "The calculation of errors by the method of least squares",
   Phys. Rev. 40 (1932) 207: the scale factor sqrt(chi2 / dof) of a weighted fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = ("X", "Y", "Z")
PLANES = {"XY": ("X", "Y"), "YZ": ("Y", "Z"), "ZX": ("Z", "X")}
# The map's candidate forms, simplest first (the one-standard-error rule picks the simplest).
FORMS = ("constant", "linear", "cubic", "quadratic")
# Decay of the lag-1 autocorrelation correction: the slopes' residuals along the path are
# widened by (1 + rho) / (1 - rho) when rho > 0, as models.machine.circle does for its fit.
MAX_RHO = 0.9


def component(first: str, second: str) -> str:
    """The compliance component of two axes, in X, Y, Z order: ('Z', 'X') -> 'XZ'."""
    a, b = sorted((first, second), key=AXES.index)
    return a + b


# ----------------------------------------------------------------------- one centre
def load_slopes(runs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The load-proportional part of the radial deviation at each angle [um/N].

    The runs of each direction are read on the angles of its longest run (linear
    interpolation round the circle; exact where the runs share their angles, as a ballbar
    reading at a fixed rate does), and at each angle the deviation is regressed on the load by
    least squares, :math:`\\Delta r = g_d(\\theta) + s(\\theta) F`:

    .. math:: s(\\theta) = \\frac{\\sum_k (F_k - \\bar F)(\\Delta r_k - \\overline{\\Delta r})}
                                  {\\sum_k (F_k - \\bar F)^2}

    Parameters
    ----------
    runs : sequence of (direction, load_n, angle_deg, deviation_um)
        Every run of one centre and plane: its direction (CW or CCW), load [N], angles [deg]
        and radial deviations [um].

    Returns
    -------
    angle_deg, slope_um_per_n, series : ndarray
        The angles, the slope at each, and the index of the direction's series (0, 1) each
        slope belongs to; a direction run at fewer than two loads gives none.
    """
    angles, slopes, series = [], [], []
    directions = list(dict.fromkeys(d for d, *_ in runs))
    for index, direction in enumerate(directions):
        mine = [r for r in runs if r[0] == direction]
        loads = np.array([r[1] for r in mine], float)
        if np.ptp(loads) == 0:
            continue
        grid = np.mod(max(mine, key=lambda r: len(r[2]))[2], 360.0)
        table = np.stack([_on(grid, a, v) for _, _, a, v in mine])  # (runs, angles)
        f = loads - loads.mean()
        slope = f @ (table - table.mean(axis=0)) / (f @ f)
        angles.append(grid)
        slopes.append(slope)
        series.append(np.full(grid.shape, index))
    if not angles:
        return np.empty(0), np.empty(0), np.empty(0, int)
    return np.concatenate(angles), np.concatenate(slopes), np.concatenate(series)


def _on(grid: np.ndarray, angle_deg: np.ndarray, deviation_um: np.ndarray) -> np.ndarray:
    a = np.mod(np.asarray(angle_deg, float), 360.0)
    order = np.argsort(a)
    return np.interp(grid, a[order], np.asarray(deviation_um, float)[order], period=360.0)


@dataclass(frozen=True)
class PlaneCompliance:
    """The compliance of one plane at one centre.

    Attributes
    ----------
    plane : str
        'XY', 'YZ' or 'ZX'.
    compliance_um_per_n : ndarray, shape (2, 2)
        [[c_aa, c_ab], [c_ab, c_bb]] in the plane's axis order [um/N].
    covariance : ndarray, shape (3, 3)
        Covariance of (c_aa, c_ab, c_bb) [(um/N)^2]: the slopes' fit, :math:`s^2 (A^T A)^{-1}`
        with :math:`s^2` = RSS / (n - p), widened by :math:`(1 + \\rho) / (1 - \\rho)` for a
        positive lag-1 autocorrelation :math:`\\rho` of the residuals along the path.
    rms_residual_um_per_n : float
        Root mean square of the slopes about the fit [um/N].
    slopes : int
        Angles that gave a slope.
    """

    plane: str
    compliance_um_per_n: np.ndarray
    covariance: np.ndarray
    rms_residual_um_per_n: float
    slopes: int

    @property
    def axes(self) -> tuple[str, str]:
        return PLANES[self.plane]

    @property
    def stiffness_n_per_um(self) -> dict:
        """k_a = 1 / c_aa per axis of the plane [N/um]."""
        c = self.compliance_um_per_n
        return {a: 1.0 / c[i, i] for i, a in enumerate(self.axes)}

    @property
    def stiffness_u_n_per_um(self) -> dict:
        """Standard uncertainty of each stiffness, u(k) = u(c) / c^2 [N/um]."""
        c, cov = self.compliance_um_per_n, self.covariance
        return {a: float(np.sqrt(cov[j, j]) / c[i, i] ** 2)
                for (i, a), j in zip(enumerate(self.axes), (0, 2))}

    @property
    def components(self) -> dict:
        """Component name ('XY', 'XX'...) -> (value [um/N], standard uncertainty [um/N])."""
        a, b = self.axes
        c, cov = self.compliance_um_per_n, self.covariance
        return {component(a, a): (float(c[0, 0]), float(np.sqrt(cov[0, 0]))),
                component(a, b): (float(c[0, 1]), float(np.sqrt(cov[1, 1]))),
                component(b, b): (float(c[1, 1]), float(np.sqrt(cov[2, 2])))}


def plane_compliance(plane: str, angle_deg, slope_um_per_n, series=None) -> PlaneCompliance:
    """The plane's compliance from the load slopes at each angle (``load_slopes``).

    .. math:: s(\\theta) = m_0 + m_2 \\cos 2\\theta + n_2 \\sin 2\\theta
              + m_{1,d} \\cos\\theta + n_{1,d} \\sin\\theta,
              \\quad c_{aa} = m_0 + m_2,\\; c_{bb} = m_0 - m_2,\\; c_{ab} = n_2

    Parameters
    ----------
    plane : str
        'XY', 'YZ' or 'ZX' (first axis along 0 deg).
    angle_deg, slope_um_per_n : array-like
        Angles [deg] and the slope of the radial deviation on the load there [um/N].
    series : array-like of int, optional
        The path each slope belongs to (a direction): the autocorrelation of the residuals is
        taken along each, in angle order.

    Returns
    -------
    PlaneCompliance
    """
    t = np.radians(np.asarray(angle_deg, float))
    s = np.asarray(slope_um_per_n, float)
    series = np.zeros(t.shape, int) if series is None else np.asarray(series)
    # the 1-per-revolution terms per path: a pivot moved between the runs of one direction
    # leaves a load-correlated centre shift of its own in that direction's slopes
    shifts = [np.column_stack([np.cos(t), np.sin(t)]) * (series == k)[:, None]
              for k in np.unique(series)]
    design = np.column_stack([np.ones_like(t), np.cos(2 * t), np.sin(2 * t), *shifts])
    coef, *_ = np.linalg.lstsq(design, s, rcond=None)
    residual = s - design @ coef
    dof = max(len(s) - design.shape[1], 1)
    variance = float(residual @ residual) / dof
    rho = _lag1(residual, t, series)
    widen = (1 + rho) / (1 - rho) if rho > 0 else 1.0
    cov_coef = variance * widen * np.linalg.pinv(design.T @ design)
    # (c_aa, c_ab, c_bb) = J (m0, m2, n2)
    jac = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, -1.0, 0.0]])
    values = jac @ coef[:3]
    cov = jac @ cov_coef[:3, :3] @ jac.T
    c = np.array([[values[0], values[1]], [values[1], values[2]]])
    return PlaneCompliance(plane, c, cov, float(np.sqrt(np.mean(residual ** 2))), len(s))


def _lag1(residual: np.ndarray, t: np.ndarray, series: np.ndarray) -> float:
    """Lag-1 autocorrelation of the residuals along each series in angle order, pooled."""
    num = den = 0.0
    for k in np.unique(series):
        r = residual[series == k][np.argsort(t[series == k])]
        num += float(r[1:] @ r[:-1])
        den += float(r @ r)
    return min(num / den, MAX_RHO) if den > 0 else 0.0


def centre_compliance(plane: str, runs) -> PlaneCompliance | None:
    """``plane_compliance`` of one centre's runs (``load_slopes``); None when no direction was
    run at two loads or more."""
    angle, slope, series = load_slopes(runs)
    if slope.size == 0:
        return None
    return plane_compliance(plane, angle, slope, series)


# ----------------------------------------------------------------------- the map
def design(form: str, centre_mm, ram_top_mm: float | None = None) -> np.ndarray:
    """The map's columns at the points ``centre_mm`` (n, 3) [mm] for ``form``.

    Positions are scaled to metres (extension e in m) so that the columns are of similar size.

    ``constant``: 1; ``linear``: 1, x, y, z; ``quadratic``: 1, x, y, z, z^2; ``cubic``: 1, x,
    y, e^3 with e = ``ram_top_mm`` - z (needs it).
    """
    p = np.atleast_2d(np.asarray(centre_mm, float)) / 1000.0
    one = np.ones(len(p))
    x, y, z = p.T
    if form == "constant":
        return one[:, None]
    if form == "linear":
        return np.column_stack([one, x, y, z])
    if form == "quadratic":
        return np.column_stack([one, x, y, z, z * z])
    if form == "cubic":
        if ram_top_mm is None:
            raise ValueError("the cubic form needs ram_top_mm")
        e = ram_top_mm / 1000.0 - z
        return np.column_stack([one, x, y, e ** 3])
    raise ValueError(f"unknown form {form!r}; expected one of {', '.join(FORMS)}")


def identifiable(form: str, centre_mm, ram_top_mm: float | None = None) -> bool:
    """The form can be fitted and cross-validated: full column rank, and at least one centre
    more than it has terms."""
    if form == "cubic" and ram_top_mm is None:
        return False
    a = design(form, centre_mm, ram_top_mm)
    return len(a) > a.shape[1] and np.linalg.matrix_rank(a) == a.shape[1]


def _wls(a: np.ndarray, value: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares: coefficients and their covariance, scaled by the Birge ratio
    chi2 / dof when the centres scatter more than their uncertainties say [Birge1932]_."""
    w = 1.0 / u
    coef, *_ = np.linalg.lstsq(a * w[:, None], value * w, rcond=None)
    cov = np.linalg.pinv((a * w[:, None] ** 2).T @ a)
    dof = len(value) - a.shape[1]
    if dof > 0:
        chi2 = float(np.sum(((value - a @ coef) * w) ** 2))
        cov = cov * max(1.0, chi2 / dof)
    return coef, cov


@dataclass(frozen=True)
class StiffnessMap:
    """Compliance over the workspace: one linear model per component.

    Attributes
    ----------
    form : str
        One of ``FORMS``.
    ram_top_mm : float or None
        z where the ram's extension is zero [mm] (the cubic form).
    components : dict
        Component ('XX', 'XY', 'YY', ...) -> (coefficients, covariance) of its model.
    cv : dict
        Form -> the leave-one-centre-out score (mean squared standardised error, summed over
        the components) and its standard error; the forms that could not be fitted are absent.
    decided : bool
        The cross-validation told the chosen form from every other of as few terms.
    reason : str
        How the form was chosen, in a sentence.
    """

    form: str
    ram_top_mm: float | None
    components: dict
    cv: dict = field(default_factory=dict)
    decided: bool = True
    reason: str = ""

    def compliance(self, point_mm) -> tuple[np.ndarray, np.ndarray]:
        """Compliance matrices at the points (m, 3) [mm] and their standard uncertainties, each
        (m, 3, 3) [um/N]; NaN where no loaded circle measured the component."""
        a = design(self.form, point_mm, self.ram_top_mm)
        value = np.full((len(a), 3, 3), np.nan)
        u = np.full((len(a), 3, 3), np.nan)
        for name, (coef, cov) in self.components.items():
            i, j = AXES.index(name[0]), AXES.index(name[1])
            v = a @ coef
            s = np.sqrt(np.einsum("ni,ij,nj->n", a, cov, a))
            value[:, i, j] = value[:, j, i] = v
            u[:, i, j] = u[:, j, i] = s
        return value, u

    def to_dict(self) -> dict:
        return {"form": self.form, "terms": terms(self.form), "ram_top_mm": self.ram_top_mm,
                "position_unit": "m",
                "components": {name: {"coefficients_um_per_n": [float(c) for c in coef],
                                      "u_um_per_n": [float(np.sqrt(v)) for v in np.diag(cov)]}
                               for name, (coef, cov) in self.components.items()},
                "cv": self.cv, "decided": self.decided, "reason": self.reason}


def terms(form: str) -> list[str]:
    """The names of the form's columns (positions in m)."""
    return {"constant": ["1"], "linear": ["1", "x", "y", "z"],
            "quadratic": ["1", "x", "y", "z", "z^2"],
            "cubic": ["1", "x", "y", "(ram_top - z)^3"]}[form]


def fit_form(form: str, centre_mm, values: dict, ram_top_mm: float | None = None) -> dict:
    """Each component's model of ``form``: component -> (coefficients, covariance).

    ``values``: component -> (centre index array, value [um/N], standard uncertainty [um/N]).
    """
    p = np.atleast_2d(np.asarray(centre_mm, float))
    out = {}
    for name, (index, value, u) in values.items():
        out[name] = _wls(design(form, p[index], ram_top_mm), value, u)
    return out


def cv_score(form: str, centre_mm, values: dict, ram_top_mm: float | None = None
             ) -> tuple[float, float]:
    """Leave-one-centre-out cross-validation of ``form``: the mean over centres of the squared
    standardised prediction error :math:`((c - \\hat c_{-i}) / u)^2`, summed over the
    components, and its standard error across centres [Hastie2009]_."""
    p = np.atleast_2d(np.asarray(centre_mm, float))
    per_centre = np.zeros(len(p))
    for index, value, u in values.values():
        a = design(form, p[index], ram_top_mm)
        for k in range(len(index)):
            keep = np.arange(len(index)) != k
            coef, _ = _wls(a[keep], value[keep], u[keep])
            per_centre[index[k]] += ((value[k] - a[k] @ coef) / u[k]) ** 2
    return float(per_centre.mean()), float(per_centre.std(ddof=1) / np.sqrt(len(p)))


def choose_map(centre_mm, values: dict, ram_top_mm: float | None = None,
               form: str = "auto") -> tuple[StiffnessMap, list[str]]:
    """Fit the stiffness map; the form by cross-validation (``form="auto"``) or as asked.

    Among the identifiable ``FORMS`` the one-standard-error rule picks the form with fewest
    terms whose leave-one-centre-out score lies within one standard error of the best
    [Hastie2009]_. When another form of as few terms lies within it too, the centres cannot
    tell them apart: the map says so (``decided`` False) and keeps the better score.

    Parameters
    ----------
    centre_mm : array-like, shape (n, 3)
        The centres [mm].
    values : dict
        Component -> (centre indices, value [um/N], standard uncertainty [um/N]).
    ram_top_mm : float, optional
        z of the ram's zero extension [mm]; without it the cubic form is not a candidate.
    form : str
        'auto' or one of ``FORMS``; a form the centres cannot carry falls back to the largest
        one they can (a note says so).

    Returns
    -------
    StiffnessMap, list of str
        The map and the notes.
    """
    p = np.atleast_2d(np.asarray(centre_mm, float))
    notes = []
    # each component must carry the form: the fewest centres of any component decide
    def ok(f):
        return all(identifiable(f, p[index], ram_top_mm) for index, *_ in values.values())

    usable = [f for f in FORMS if ok(f)]
    heights = len(np.unique(np.round(p[:, 2], 6)))
    if form != "auto":
        if form in usable:
            return StiffnessMap(form, ram_top_mm, fit_form(form, p, values, ram_top_mm),
                                reason=f"{form}, as asked"), notes
        fallback = max(usable or ["constant"], key=lambda f: design(f, p[:1], ram_top_mm)
                       .shape[1]) if usable else "constant"
        need = design(form, p[:1], ram_top_mm).shape[1] + 1
        why = (f"{len(p)} centres at {heights} heights cannot carry the {form} map (it needs at "
               f"least {need} centres spread over enough heights and places)")
        notes.append(f"{why}: falling back to {fallback}")
        return StiffnessMap(fallback, ram_top_mm, fit_form(fallback, p, values, ram_top_mm),
                            decided=False, reason=f"{fallback}, fallen back from {form}"), notes
    if ram_top_mm is None:
        notes.append("the cubic ram map (compliance growing with the cube of the ram's "
                     "extension) is not a candidate without ram_top_mm, the z of the ram's zero "
                     "extension")
    if len(usable) <= 1:
        notes.append(f"{len(p)} centres at {heights} heights are too few to choose the map: it "
                     "is constant over the workspace (the mean of the centres, weighted by "
                     "their uncertainty)")
        return StiffnessMap("constant", ram_top_mm, fit_form("constant", p, values, ram_top_mm),
                            decided=False, reason="too few centres: constant"), notes
    scores = {f: cv_score(f, p, values, ram_top_mm) for f in usable}
    best = min(scores, key=lambda f: scores[f][0])
    limit = scores[best][0] + scores[best][1]
    size = {f: design(f, p[:1], ram_top_mm).shape[1] for f in usable}
    within = [f for f in usable if scores[f][0] <= limit]
    fewest = min(size[f] for f in within)
    tied = sorted((f for f in within if size[f] == fewest), key=lambda f: scores[f][0])
    chosen = tied[0]
    decided = len(tied) == 1
    reason = (f"{chosen}: leave-one-centre-out cross-validation, the fewest terms within one "
              "standard error of the best")
    if not decided:
        notes.append(f"the {len(p)} centres at {heights} heights cannot tell the "
                     f"{' and the '.join(tied)} maps apart (cross-validation within one standard "
                     f"error): kept {chosen}; centres at more heights would decide")
    missing = [f for f in FORMS if f not in usable and (f != "cubic" or ram_top_mm is not None)]
    if missing:
        notes.append(f"not cross-validated, too few centres or heights: {', '.join(missing)}")
    cv = {f: {"score": s, "se": e} for f, (s, e) in scores.items()}
    return StiffnessMap(chosen, ram_top_mm, fit_form(chosen, p, values, ram_top_mm), cv=cv,
                        decided=decided, reason=reason), notes


def deflection_um(stiffness_map: StiffnessMap, point_mm, force_n) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """The deflection under a quasi-static force, :math:`\\delta = C(p) F`, and its standard
    uncertainty.

    Parameters
    ----------
    stiffness_map : StiffnessMap
    point_mm : array-like, shape (m, 3)
        Where [mm].
    force_n : array-like, shape (m, 3)
        The force on the tool at each point [N] (a zero component needs no compliance).

    Returns
    -------
    deflection_um, u_um : ndarray, shape (m, 3)
        :math:`\\delta_i = \\sum_j C_{ij} F_j`, and
        :math:`u(\\delta_i)^2 = \\sum_j F_j^2 u(C_{ij})^2` (the components' map errors taken
        as independent); NaN where a component the force needs was not measured.
    """
    f = np.atleast_2d(np.asarray(force_n, float))
    c, u = stiffness_map.compliance(point_mm)
    used = f[:, None, :] != 0
    c = np.where(used, c, 0.0)
    u = np.where(used, u, 0.0)
    d = np.einsum("mij,mj->mi", c, f)
    s = np.sqrt(np.einsum("mij,mj->mi", u ** 2, f ** 2))
    return d, s


def map_from_json(saved: dict) -> StiffnessMap:
    """A map written by ``backlash stiffness --out`` (``StiffnessMap.to_dict`` plus
    ``covariance``: component -> its coefficients' covariance) back as a ``StiffnessMap``.

    Raises
    ------
    KeyError
        A map without its form, coefficients or covariances.
    """
    components = {name: (np.asarray(value["coefficients_um_per_n"], float),
                         np.asarray(saved["covariance"][name], float))
                  for name, value in saved["components"].items()}
    return StiffnessMap(saved["form"], saved.get("ram_top_mm"), components,
                        cv=saved.get("cv", {}), decided=saved.get("decided", True),
                        reason=saved.get("reason", ""))


def map_values(found) -> tuple[np.ndarray, dict]:
    """The inputs of ``choose_map`` from the centres' compliances.

    Parameters
    ----------
    found : iterable of (centre_mm, PlaneCompliance)
        Each centre's position (3,) [mm] and the compliance of a plane there.

    Returns
    -------
    ndarray, dict
        The distinct centre positions (n, 3) [mm]; component -> (centre indices, values
        [um/N], standard uncertainties [um/N]) (a centre measured in two planes gives a
        component shared by both twice).
    """
    keys, positions, values = {}, [], {}
    for centre_mm, pc in found:
        key = tuple(np.round(np.asarray(centre_mm, float), 6))
        if key not in keys:
            keys[key] = len(positions)
            positions.append(np.asarray(centre_mm, float))
        for name, (value, u) in pc.components.items():
            triple = values.setdefault(name, ([], [], []))
            for target, v in zip(triple, (keys[key], value, u)):
                target.append(v)
    return (np.array(positions), {n: tuple(np.array(v) for v in t) for n, t in values.items()})
