"""Volumetric compensation: identify the 21 geometric errors from laser tests taken off the tool
point, compensate with the traditional or the Abbe-aware model, measure the body diagonals.

A laser test of axis k reads, at its optics h_L (not at the tool point h_T), three
translations and three angles while k moves and the other axes stand still. To first order
(``models.physics.machine.tool_error_um``) the translations are

    m(q) = s_k [delta_k(q) + eps_k(q) x lever_k(h_L)] + (terms of the standing axes),

s_k = -1 for the table axes. The angles give eps_k directly (they are the same anywhere on a
rigid carriage). Identification inverts the relation for delta_k at the reading head,
given the lever it believes in [Chen2022]_ eq. (2)-(3):

- **traditional**: the optics are taken to be at the tool point (lever_k(h_T)), so the
  measured translations are used as the tool's and the Abbe error eps_k x (h_L - h_T) stays
  in them;
- **Abbe-aware**: the optics' true offset is used (lever_k(h_L)): eps_k x lever_k(h_L) is
  removed and the model adds eps_k x lever_k(h_T) back at the tool point (eq. (4)).

Every error function is fitted as a polynomial whose degree generalised cross-validation
chooses from the data (``fit_smooth``): the data, not the twin's shapes, set its form.
Straightness is kept with its least-squares line removed and the lines are reported as the
three squareness errors, the convention of the twin (ISO 230-1).

References
----------
.. [Chen2022] G. Chen et al. (seed 001), "Modeling Method of CNC Machine Tools' Volume Error Considering
   Abbe Error", equations (1)-(4), Table 1.
.. ISO 230-1 (geometric accuracy), ISO 230-2 (positioning), ISO 230-6 (body diagonals).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from models.physics import machine as twin

MODELS = ("traditional", "abbe")
# Offsets of the laser's optics from the spindle reference for each axis' test [mm] (the paper
# does not give them; plausible for optics clamped beside and above a long tool), and where the
# standing axes wait during each test (x, y, z) [mm].
PAPER_LASER_MM = {"X": np.array([0.0, 250.0, 150.0]), "Y": np.array([-250.0, 0.0, 150.0]),
                  "Z": np.array([200.0, 200.0, -150.0])}
PAPER_ORIGIN_MM = np.array([750.0, -1800.0, -350.0])
PAPER_NOISE = {"positioning_um": 0.3, "straightness_um": 0.5, "angle_urad": 0.3,
               "roll_urad": 1.0, "diagonal_um": 0.3}


@dataclass(frozen=True)
class Setup:
    """How the 21 errors are measured: one six-channel laser test per axis.

    Attributes
    ----------
    laser_mm : dict of str to ndarray
        Axis -> the optics' point relative to the spindle reference during its test [mm].
    origin_mm : ndarray, shape (3,)
        Where the standing axes wait during each test [mm].
    targets : int
        Targets along each axis (the paper: 11, 150 / 150 / 110 mm apart).
    cycles : int
        Bidirectional cycles (ISO 230-2: 5); the mean of both directions cancels the play.
    noise : dict
        Standard deviations: ``positioning_um``, ``straightness_um``, ``angle_urad`` (pitch,
        yaw), ``roll_urad`` (an electronic level), ``diagonal_um``.
    """

    laser_mm: dict = field(default_factory=lambda: dict(PAPER_LASER_MM))
    origin_mm: np.ndarray = field(default_factory=lambda: PAPER_ORIGIN_MM.copy())
    targets: int = 11
    cycles: int = 5
    noise: dict = field(default_factory=lambda: dict(PAPER_NOISE))

    def channel_noise(self, axis: str) -> dict:
        """The noise of each reading channel of ``axis``' test."""
        j = twin.AXES.index(axis)
        n = self.noise
        sd = {c: n["straightness_um"] for c in twin.CHANNELS[:3]}
        sd[twin.CHANNELS[j]] = n["positioning_um"]
        sd.update({c: n["angle_urad"] for c in twin.CHANNELS[3:]})
        sd[twin.CHANNELS[3 + j]] = n["roll_urad"]
        return sd


def axis_line(travel_mm: dict, origin_mm, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (x, y, z) [mm] of ``axis``' full travel, the others at ``origin_mm``."""
    j = twin.AXES.index(axis)
    start, end = np.array(origin_mm, float), np.array(origin_mm, float)
    start[j], end[j] = travel_mm[axis]
    return start, end


def measure_axes(machine: twin.Machine, setup: Setup, rng: np.random.Generator) -> dict:
    """The laser tests of the three axes on the twin: axis -> the readings frame of
    ``models.physics.machine.line_test`` (six channels at the axis' optics)."""
    tests = {}
    for axis in twin.AXES:
        start, end = axis_line(machine.geometry.travel_mm, setup.origin_mm, axis)
        tests[axis] = twin.line_test(machine, start, end, targets=setup.targets,
                                     cycles=setup.cycles, point_mm=setup.laser_mm[axis],
                                     noise=setup.channel_noise(axis), rng=rng)
    return tests


def fit_smooth(q, values, max_degree: int = 8) -> np.polynomial.Polynomial:
    """A polynomial through noisy values whose degree generalised cross-validation chooses.

    GCV(d) = n RSS_d / (n - d - 1)^2 over degrees 1..min(max_degree, n - 3) [Craven & Wahba
    1979]: the degree that best predicts left-out points, set by the data.

    Parameters
    ----------
    q : array-like
        Positions [mm].
    values : array-like
        Values at ``q`` (um or urad).
    max_degree : int
        The highest degree tried.
    """
    q, values = np.asarray(q, float), np.asarray(values, float)
    n = len(q)
    best, best_score = None, np.inf
    for degree in range(1, max(1, min(max_degree, n - 3)) + 1):
        poly = np.polynomial.Polynomial.fit(q, values, degree)
        rss = float(np.sum((poly(q) - values) ** 2))
        score = n * rss / (n - degree - 1) ** 2
        if score < best_score * (1 - 1e-9):
            best, best_score = poly, score
    return best


def _target_means(test: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Each target's position along the axis [mm] and the mean of its readings over every
    cycle and both directions (six channels): the bidirectional mean cancels the play."""
    means = test.groupby("target")[[*twin.CHANNELS, "distance_mm"]].mean()
    return means["distance_mm"].to_numpy(), means[list(twin.CHANNELS)].to_numpy()


def _lever(axis: str, position_mm: np.ndarray, point_mm, head_mm) -> np.ndarray:
    """Lever [mm] from ``axis``' reading head to a spindle point with the machine at
    ``position_mm``: h + z e_z - R_k for the tables, h - R_Z for the ram."""
    lever = np.broadcast_to(np.asarray(point_mm, float) - head_mm, position_mm.shape).copy()
    if axis in twin.TABLE_AXES:
        lever[:, 2] += position_mm[:, 2]
    return lever


def identify(tests: dict, setup: Setup, travel_mm: dict, reading_head_mm: dict,
             measured_at: dict, samples: int = 1501) -> twin.Geometry:
    """The 21 geometric errors from the three axes' laser tests.

    Per axis: the angles are fitted from the angular channels; the translations at the
    reading head are the target means of the linear channels less eps x lever(``measured_at``)
    (the paper's eq. (3) inverted), then fitted. The straightness channels are read against
    a reference aligned with the machine's axes (an optical square, ISO 230-1), so their
    lines give the squareness. Axes are identified in the order X, Y, Z: the Z test sees the
    tables' angles where they stand (times z), which the X and Y fits remove.

    Parameters
    ----------
    tests : dict
        Axis -> readings frame (``measure_axes``).
    setup : Setup
        Where the standing axes waited.
    travel_mm, reading_head_mm : dict
        The machine's travels and reading heads (its drawings).
    measured_at : dict
        Axis -> the point [mm] the identification takes the optics to be at: the optics' true
        place for the Abbe-aware model, the tool point for the traditional one.
    samples : int
        Points of the tabulated result along each travel.

    Returns
    -------
    models.physics.machine.Geometry
        Positioning and angles zero at the start of travel, straightness without its line, the
        lines as squareness [urad].
    """
    tables, angle_fits, slopes = {}, {}, {}
    for axis in twin.AXES:
        j = twin.AXES.index(axis)
        sign = -1.0 if axis in twin.TABLE_AXES else 1.0
        lo, hi = travel_mm[axis]
        start, end = axis_line(travel_mm, setup.origin_mm, axis)
        distance, means = _target_means(tests[axis])
        q = lo + distance * np.sign(hi - lo)
        positions = start + np.outer(distance / np.linalg.norm(end - start), end - start)
        # the spindle turns by -eps of a table; angles are zero at the start of travel
        fits = [f - f(lo) for f in (fit_smooth(q, sign * means[:, 3 + c]) for c in range(3))]
        angle_fits[axis] = fits
        standing = _standing_tilt_um(axis, positions, setup.origin_mm, angle_fits)
        eps = np.stack([f(q) for f in fits], axis=1)
        lever = _lever(axis, positions, measured_at[axis], reading_head_mm[axis])
        delta = sign * (means[:, :3] - standing) - twin.cross_um(eps, lever)
        u = np.linspace(0.0, 1.0, samples)
        grid = lo + u * (hi - lo)
        values = np.column_stack([fit_smooth(q, delta[:, c])(grid) for c in range(3)]
                                 + [f(grid) for f in fits])
        for c in range(3):
            if c != j:
                slopes[axis, c] = np.polyfit(grid, values[:, c], 1)[0] * 1e3  # [urad]
        tables[axis] = twin.ErrorTable(grid, twin.conventional(axis, values, u))
    return twin.Geometry(errors=tables, squareness_urad=_squareness_urad(slopes),
                         reading_head_mm=dict(reading_head_mm), travel_mm=dict(travel_mm))


def _standing_tilt_um(axis: str, positions: np.ndarray, origin_mm, angle_fits: dict
                      ) -> np.ndarray:
    """What the standing tables add to a test [um], shape (n, 3): on the ram's test they stand
    tilted by eps where they wait, and z lengthens their lever, -eps x (z - z_0) e_z; on the
    tables' own tests z does not move and they add nothing."""
    out = np.zeros_like(positions)
    if axis in twin.TABLE_AXES:
        return out
    rise = np.zeros_like(positions)
    rise[:, 2] = positions[:, 2] - positions[0, 2]
    for other in twin.TABLE_AXES:
        tilt = np.array([f(origin_mm[twin.AXES.index(other)]) for f in angle_fits[other]])
        out -= twin.cross_um(np.broadcast_to(tilt, positions.shape), rise)
    return out


def _squareness_urad(slopes: dict) -> dict:
    """The three squareness errors [urad] from the straightness lines' slopes [urad].

    A line of slope s in axis k's straightness along i adds E_i = -/+ s P_k (the tables' with
    a minus sign, the ram's with a plus): the field's linear part L_ik. Of each pair only the
    symmetric part L_ik + L_ki changes distances (the rest turns the whole frame), and the
    convention E_x = a_XY y, E_x = a_XZ z, E_y = a_YZ z puts all of it on one side.
    """
    return {"XY": -slopes["Y", 0] - slopes["X", 1],
            "XZ": slopes["Z", 0] - slopes["X", 2],
            "YZ": slopes["Z", 1] - slopes["Y", 2]}


def identify_both(machine: twin.Machine, setup: Setup, tests: dict) -> dict[str, twin.Geometry]:
    """The traditional and the Abbe-aware identifications of the same tests, by model name."""
    g = machine.geometry
    believed = {"traditional": {a: machine.tool_mm for a in twin.AXES},
                "abbe": dict(setup.laser_mm)}
    return {name: identify(tests, setup, g.travel_mm, g.reading_head_mm, believed[name])
            for name in MODELS}


def compensation(model: twin.Geometry, tool_mm):
    """The control's correction: P (n, 3) [mm] -> the model's tool error at P [um]."""
    return lambda position_mm: twin.tool_error_um(model, position_mm, tool_mm)


def extreme_um(deviation_um) -> float:
    """The deviation of largest magnitude, with its sign (the paper's "maximum")."""
    d = np.asarray(deviation_um, float)
    return float(d[np.argmax(np.abs(d))])


def _laser_noise(sd_um: float) -> dict:
    """A linear laser's noise on the three translation channels [um]."""
    return {c: sd_um for c in twin.CHANNELS[:3]}


def measure_diagonals(machine: twin.Machine, setup: Setup, rng: np.random.Generator,
                      correction=None) -> dict[str, pd.DataFrame]:
    """The four ISO 230-6 body diagonals, stepped forward as the paper does (``targets``
    targets, laser at the tool point), with an optional compensation: name -> readings."""
    noise = _laser_noise(setup.noise["diagonal_um"])
    return {name: twin.line_test(machine, start, end, targets=setup.targets, bidirectional=False,
                                 noise=noise, rng=rng, compensation=correction)
            for name, (start, end) in twin.body_diagonals(machine.geometry.travel_mm).items()}


def measure_positioning(machine: twin.Machine, setup: Setup, rng: np.random.Generator,
                        correction=None) -> dict[str, pd.DataFrame]:
    """Each axis' positioning at the tool point (forward, ``targets`` targets): axis -> readings."""
    noise = _laser_noise(setup.noise["positioning_um"])
    return {axis: twin.line_test(machine, *axis_line(machine.geometry.travel_mm,
                                                     setup.origin_mm, axis),
                                 targets=setup.targets, bidirectional=False, noise=noise,
                                 rng=rng, compensation=correction)
            for axis in twin.AXES}


STAGES = ("before", *MODELS)


@dataclass
class Comparison:
    """Before and after compensation with each model, on one twin and one seed.

    Attributes
    ----------
    models : dict of str to Geometry
        The traditional and the Abbe-aware identifications.
    diagonals : DataFrame
        Every diagonal reading: ``diagonal``, ``stage`` (before, traditional, abbe),
        ``target``, ``distance_mm``, ``deviation_um``.
    positioning : DataFrame
        Every axis' positioning reading at the tool point: ``axis``, ``stage``, ``target``,
        ``distance_mm``, ``deviation_um``.
    """

    models: dict
    diagonals: pd.DataFrame
    positioning: pd.DataFrame

    def extremes(self, what: str = "diagonals") -> dict:
        """Per diagonal (or axis): the extreme deviation [um] of each stage, the paper's
        "maximum": {name: {"before_um", "traditional_um", "abbe_um"}}."""
        frame, key = (self.diagonals, "diagonal") if what == "diagonals" else (
            self.positioning, "axis")
        return {name: {f"{stage}_um": extreme_um(part.loc[part["stage"] == stage,
                                                          "deviation_um"])
                       for stage in STAGES}
                for name, part in frame.groupby(key, sort=False)}


def _stacked(runs: dict, key: str) -> pd.DataFrame:
    """{stage: {name: readings}} -> one frame with ``key`` and ``stage`` columns."""
    return pd.concat([f[["target", "distance_mm", "deviation_um"]].assign(**{key: name},
                                                                           stage=stage)
                      for stage, by_name in runs.items() for name, f in by_name.items()],
                     ignore_index=True)[[key, "stage", "target", "distance_mm", "deviation_um"]]


def compare(machine: twin.Machine, setup: Setup, seed: int = 0) -> Comparison:
    """Measure the axes, identify both models, and measure the diagonals and the axes'
    positioning before and after compensation with each (one random stream: the same seed
    gives the same numbers)."""
    rng = np.random.default_rng(seed)
    models = identify_both(machine, setup, measure_axes(machine, setup, rng))
    corrections = {"before": None, **{n: compensation(g, machine.tool_mm)
                                      for n, g in models.items()}}
    diagonals = {s: measure_diagonals(machine, setup, rng, c) for s, c in corrections.items()}
    axes = {s: measure_positioning(machine, setup, rng, c) for s, c in corrections.items()}
    return Comparison(models=models, diagonals=_stacked(diagonals, "diagonal"),
                      positioning=_stacked(axes, "axis"))


def identification_error(model: twin.Geometry, truth: twin.Geometry, samples: int = 301) -> dict:
    """How far an identification is from the truth: per axis and channel the largest
    |identified - true| over the travel [um or urad], and per pair the squareness error [urad]."""
    out = {}
    for axis in twin.AXES:
        q = np.linspace(*truth.travel_mm[axis], samples)
        gap = np.abs(model.errors[axis](q) - truth.errors[axis](q)).max(axis=0)
        out[axis] = dict(zip(twin.CHANNELS, map(float, gap)))
    out["squareness_urad"] = {k: float(model.squareness_urad[k] - truth.squareness_urad[k])
                              for k in twin.SQUARENESS}
    return out
