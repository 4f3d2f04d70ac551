"""Named physical effects of a ball-screw feed axis: one record and one function each.

Every name of the vocabulary (``docs/data-contract.md``, section 4, except ``none``) has a pure
function of arrays, in the manner of pvlib's ``temperature.py``: inputs with units in their
names, parameters with physically plausible defaults, output in um. ``EFFECTS`` holds, per
effect, everything the rest of the product needs to know about it (in the spirit of pvlib's
``TEMPERATURE_MODEL_PARAMETERS``): the function, its kind and unit, which parameter is the
amplitude and its plausible range, the nuisance parameters and the grids they are searched
over, the readings it needs, the reference, the test that separates it from its look-alikes,
the one-sentence physical reading, and the named default parameter set. The twin
(``models.physics.axis``), the effect-model baseline (``models.estimators.effect_model``), the discovery
workflow (``models.discovery``) and the benchmark read only this table: adding an effect means
adding one function and one record.

Two kinds:

- ``lost_motion``: the width b [um] of the play between motor and table. The axis model runs
  the commanded path through a play operator of that width; b is the sum of the enabled
  lost-motion effects.
- ``position``: the laser reading minus the true target position [um], added to every reading.

Conditions are arrays aligned with the positions: ``feed_mm_min``, ``dwell_s``,
``machine_temp_c``, ``ambient_temp_c``, ``pressure_hpa``, ``humidity_pct`` and ``elapsed_s``
(time since the start of the run, derived from ``measured_at``). ``direction`` is +1 or -1.

Nuisance grids (``Effect.nuisance``, parameter -> grid) are either a tuple of values to try or
a word for a value the data fix: ``"targets"`` (each measured target position), ``"travel"``
(the measured travel), ``"middle"``, ``"start"``, ``"stop"`` (of the measured travel), ``"ends"`` (either end of
the measured travel, e.g. where a fixed bearing can sit),
``"quadrature"`` (a phase fitted in closed form as a sine and a cosine column, with the
record's amplitude; ``("quadrature", amplitude_parameter)`` for another harmonic),
``"per_target"`` (a number of control points from 3 up to one per measured target, chosen by
the information criterion) and ``("period", low, high)`` (a period between low and high,
searched in frequency steps of a quarter cycle over the measured travel, so that no period in
the range falls between two grid values).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.special import comb

# [Mechta2022]'s B-spline basis (eqs. 4-5), one definition for the whole package
from features.statistics import bspline_basis  # noqa: F401 - part of this module's API

REFERENCE_TEMP_C = 20.0
REFERENCE_PRESSURE_HPA = 1013.25
REFERENCE_HUMIDITY_PCT = 50.0
# Edlen sensitivities of the air's refractive index near 20 degC, 1013 hPa, 50 %RH [ppm per unit]
EDLEN_PPM_PER_K = -0.93
EDLEN_PPM_PER_HPA = 0.27
EDLEN_PPM_PER_PCT = -0.0085
STEEL_ALPHA_UM_PER_M_K = 11.5

BACKLASH_PAPER = "[BacklashNN], section 2.2.2"
ERROR_MODELS = "intra-axis error models [Mechta2022], eqs. 1-5, 18 and 20"


# ------------------------------------------------------------------------------ bases
def unit_interval(position_mm, start_mm, stop_mm) -> np.ndarray:
    """Parametric coordinate t = (x - start) / (stop - start), clipped to [0, 1] [-]."""
    span = (stop_mm - start_mm) if stop_mm != start_mm else 1.0
    return np.clip((np.asarray(position_mm, float) - start_mm) / span, 0.0, 1.0)


def bezier_basis(t, degree: int = 4) -> np.ndarray:
    """Bernstein polynomials B_i,n(t) = C(n, i) t^i (1 - t)^(n - i), i = 0..n ([Mechta2022], eqs.
    1-3); shape ``t.shape + (n + 1,)``."""
    t = np.asarray(t, float)[..., None]
    i = np.arange(degree + 1)
    return comb(degree, i) * t ** i * (1 - t) ** (degree - i)


# ------------------------------------------------------------------------------ lost motion
def backlash(position_mm, direction, conditions, b0_um=2.0):
    """Constant lost motion at reversal.

    Parameters
    ----------
    position_mm : array-like
        Target position [mm] (sets the output shape only).
    b0_um : float
        Clearance between motor and table [um].

    Returns
    -------
    b : ndarray
        Play width b = b0 [um].

    References
    ----------
    [BacklashNN], section 2.2.2.
    """
    return np.broadcast_to(np.asarray(b0_um, float), np.shape(position_mm))


def backlash_position(position_mm, direction, conditions, amplitude_um=1.0, center_mm=175.0,
                      width_mm=80.0):
    """Lost motion varying along the axis: local wear of screw and nut where the axis works
    most, as a Gaussian bump.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    amplitude_um : float
        Extra clearance at the centre of the worn zone A [um].
    center_mm, width_mm : float
        Centre c and width w of the worn zone [mm].

    Returns
    -------
    b : ndarray
        b = A exp(-((x - c) / w)^2) [um].

    References
    ----------
    [BacklashNN], section 2.2.2 (wear of the nut); the general smooth form the
    discovery workflow also tries is [Mechta2022]'s B-spline (``bspline_basis``).
    """
    return amplitude_um * np.exp(-((np.asarray(position_mm) - center_mm) / width_mm) ** 2)


def backlash_feed(position_mm, direction, conditions, k_um_per_m_min=1.0):
    """Friction windup: the drive's friction grows with speed and winds up the axial stiffness.

    Parameters
    ----------
    conditions : dict
        ``feed_mm_min``: feed rate f [mm/min].
    k_um_per_m_min : float
        Lost motion per unit of feed k [um per m/min].

    Returns
    -------
    b : ndarray
        b = k f / 1000 [um].

    References
    ----------
    [BacklashNN], section 2.2.2 (speed dependence of lost motion).
    """
    return k_um_per_m_min * np.asarray(conditions["feed_mm_min"]) / 1000.0


def backlash_temperature(position_mm, direction, conditions, k_um_per_k=-0.3):
    """Ball-nut preload changing with screw temperature.

    Parameters
    ----------
    conditions : dict
        ``machine_temp_c``: machine (screw) temperature T [degC].
    k_um_per_k : float
        Sensitivity k [um/K]; negative: a warmer nut expands onto the balls and closes the
        clearance.

    Returns
    -------
    b : ndarray
        b = k (T - 20 degC) [um].

    References
    ----------
    [BacklashNN], section 2.2.2 and Table 2 (machine temperature as an input).
    """
    return k_um_per_k * (np.asarray(conditions["machine_temp_c"]) - REFERENCE_TEMP_C)


# ------------------------------------------------------------------------------ position errors
def lead_error_linear(position_mm, direction, conditions, k_um_per_m=8.0):
    """Cumulative lead (or scale) error proportional to position.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    k_um_per_m : float
        Lead error per metre of travel k [um/m].

    Returns
    -------
    e : ndarray
        e = k x / 1000 [um].

    References
    ----------
    ISO 230-2:2014, systematic positioning deviation; [Mechta2022], section 2.
    """
    return k_um_per_m * np.asarray(position_mm) / 1000.0


def lead_error_periodic(position_mm, direction, conditions, amplitude_um=1.0, pitch_mm=10.0,
                        phase_rad=0.0, amplitude2_um=0.0, phase2_rad=0.0, amplitude_rev_um=0.0,
                        phase_rev_rad=0.0, revolution_mm=360.0):
    """Periodic lead error of the screw with its pitch as period, with its second harmonic
    (eccentric screw, wobbling nut); on a rotary table driven by a worm, the worm's error with
    the wheel's tooth pitch as period and the wheel's once-per-revolution eccentricity.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm] (rotary axis: [deg]).
    amplitude_um, amplitude2_um : float
        Amplitudes of the first and second harmonic A, A2 [um] (rotary: [arcsec]).
    pitch_mm : float
        Screw pitch p [mm]; for a worm gear with z teeth, the angle one worm turn indexes the
        table, 360 / z [deg].
    phase_rad, phase2_rad : float
        Phases phi, phi2 [rad].
    amplitude_rev_um, phase_rev_rad : float
        Once-per-revolution term A_r [arcsec], phi_r [rad]: eccentricity of the wheel or of the
        encoder disc on a rotary axis (0 on a linear axis).
    revolution_mm : float
        Period of that term, one revolution R [deg].

    Returns
    -------
    e : ndarray
        e = A sin(2 pi x / p + phi) + A2 sin(4 pi x / p + phi2) + A_r sin(2 pi x / R + phi_r)
        [um]. The screw terms are invisible when the targets are spaced at multiples of the
        pitch, hence ISO 230-2's irregular spacing.

    References
    ----------
    ISO 230-2:2014, section 4.3 (target positions with irregular spacing). A graduation of
    radius r [mm] mounted off-centre by e [um] reads an angular error of e / r [mrad] times
    sin(x + phi_r) once per revolution (A_r = 206.265 e / r arcsec).
    """
    x = np.asarray(position_mm)
    turns = 2 * np.pi * x / pitch_mm
    return (amplitude_um * np.sin(turns + phase_rad) + amplitude2_um * np.sin(2 * turns + phase2_rad)
            + amplitude_rev_um * np.sin(2 * np.pi * x / revolution_mm + phase_rev_rad))


def lead_error_profile(position_mm, direction, conditions, p0_um=0.0, p1_um=2.0, p2_um=-1.5,
                       p3_um=1.5, p4_um=0.0, start_mm=0.0, stop_mm=350.0):
    """Smooth non-linear positioning error along the axis: [Mechta2022]'s Bezier intra-axis model of
    degree 4 with five control points, what a pitch-error compensation table corrects.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    p0_um, p1_um, p2_um, p3_um, p4_um : float
        Control-point values P_i [um], evenly spaced over the travel.
    start_mm, stop_mm : float
        Travel over which the curve is defined [mm]; t = (x - start) / (stop - start).

    Returns
    -------
    e : ndarray
        e = sum_i C(4, i) t^i (1 - t)^(4 - i) P_i [um].

    References
    ----------
    Seed 000, eqs. 1-3 and 18 (Bezier model of degree 4, five control points); the discovery
    workflow fits the general form, eq. 4-5 and 20 (B-spline of degree 2), with the number of
    control points chosen by BIC.
    """
    t = unit_interval(position_mm, start_mm, stop_mm)
    points = np.stack(np.broadcast_arrays(p0_um, p1_um, p2_um, p3_um, p4_um), axis=-1)
    points = np.asarray(points, float)
    basis = bezier_basis(t, 4)
    if points.ndim > 1:  # per-test control points (tests, 1, 5) against (tests, points, 5)
        return np.sum(basis * points, axis=-1)
    return basis @ points


def reversal_profile(position_mm, direction, conditions, r0_um=4.0, r1_um=4.0, r2_um=0.0,
                     r3_um=-4.0, r4_um=-4.0, start_mm=0.0, stop_mm=350.0):
    """Direction-dependent positioning error along the axis that may change sign: the carriage
    pitches one way when driven forward and the other way when driven back (a direction-
    dependent pitch seen through an Abbe offset), or the hysteresis of screw and nut varies
    along the screw. What separate forward and reverse compensation tables correct.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    direction : array-like
        Approach direction d (+1 or -1).
    r0_um, r1_um, r2_um, r3_um, r4_um : float
        Control-point values R_i of the reversal value r(x) [um], evenly spaced over the travel.
    start_mm, stop_mm : float
        Travel over which the curve is defined [mm]; t = (x - start) / (stop - start).

    Returns
    -------
    e : ndarray
        e = (d / 2) sum_i C(4, i) t^i (1 - t)^(4 - i) R_i [um]: the reversal value at x,
        e(+) - e(-) = r(x), follows the Bezier curve, of either sign.

    Notes
    -----
    A clearance b(x) >= 0 (``backlash``, ``backlash_position``) makes the + approach read
    b/2 low and the - approach b/2 high with an indirect measuring system: its reversal value
    is -b(x) <= 0 at every target. A reversal value that changes sign along the axis, or a
    direction-dependent error at the interior targets of a linear test with a direct
    measuring system (which hides lost motion there), is not a clearance: it is this effect.

    References
    ----------
    Seed 000, eqs. 1-3 and 17 (Bezier intra-axis model; angular error through the Abbe
    offset) applied to the half-difference between the directions, ISO 230-2:2014 (reversal
    value B_i at each target); the discovery workflow fits the general form, eqs. 4-5 and 20
    (B-spline of degree 2), with the number of control points chosen by BIC.
    """
    t = unit_interval(position_mm, start_mm, stop_mm)
    points = np.stack(np.broadcast_arrays(r0_um, r1_um, r2_um, r3_um, r4_um), axis=-1)
    points = np.asarray(points, float)
    basis = bezier_basis(t, 4)
    # per-test control points (tests, 1, 5) against (tests, points, 5)
    value = np.sum(basis * points, axis=-1) if points.ndim > 1 else basis @ points
    return np.asarray(direction, float) * value / 2


def thermal_expansion(position_mm, direction, conditions, alpha_um_per_m_k=STEEL_ALPHA_UM_PER_M_K,
                      x_fixed_mm=0.0):
    """Screw expansion from its fixed bearing.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    conditions : dict
        ``machine_temp_c``: screw temperature T [degC].
    alpha_um_per_m_k : float
        Expansion coefficient alpha [um/(m K)], steel 11.5.
    x_fixed_mm : float
        Position of the fixed bearing [mm].

    Returns
    -------
    e : ndarray
        e = alpha (T - 20 degC) (x - x_fixed) / 1000 [um].

    References
    ----------
    ISO 230-3 (thermal effects); ISO 1 (reference temperature 20 degC).
    """
    dT = np.asarray(conditions["machine_temp_c"]) - REFERENCE_TEMP_C
    return alpha_um_per_m_k * dT * (np.asarray(position_mm) - x_fixed_mm) / 1000.0


def thermal_drift(position_mm, direction, conditions, amplitude_um=2.0, tau_s=900.0):
    """Warm-up drift during a run.

    Parameters
    ----------
    conditions : dict
        ``elapsed_s``: time since the start of the run t [s].
    amplitude_um : float
        Drift at the end of the warm-up A [um].
    tau_s : float
        Time constant tau [s].

    Returns
    -------
    e : ndarray
        e = A (1 - exp(-t / tau)) [um].

    References
    ----------
    ISO 230-3, thermal drift test (first-order warm-up).
    """
    return amplitude_um * (1.0 - np.exp(-np.asarray(conditions["elapsed_s"]) / tau_s))


def edlen_ppm(conditions):
    """Refractive-index change of air from its reference state [ppm], linearised Edlen:
    dn = -0.93 (T_air - 20) + 0.27 (p - 1013.25) - 0.0085 (RH - 50) [ppm] (Edlen 1966,
    Birch and Downs 1993)."""
    return (EDLEN_PPM_PER_K * (np.asarray(conditions["ambient_temp_c"]) - REFERENCE_TEMP_C)
            + EDLEN_PPM_PER_HPA * (np.asarray(conditions["pressure_hpa"]) - REFERENCE_PRESSURE_HPA)
            + EDLEN_PPM_PER_PCT * (np.asarray(conditions["humidity_pct"])
                                   - REFERENCE_HUMIDITY_PCT))


def air_refraction(position_mm, direction, conditions, fraction=1.0):
    """Uncompensated air refraction of the laser interferometer.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    conditions : dict
        ``ambient_temp_c`` [degC], ``pressure_hpa`` [hPa], ``humidity_pct`` [%RH].
    fraction : float
        Uncompensated fraction of the index change [-]; 1 means no compensation at all.

    Returns
    -------
    e : ndarray
        e = fraction * dn_ppm * x / 1000 [um] (1 ppm of 1 m is 1 um).

    References
    ----------
    Edlen (1966), Birch and Downs (1993); ISO 230-2:2014, annex A (environmental compensation).
    """
    return fraction * edlen_ppm(conditions) * np.asarray(position_mm) / 1000.0


def abbe(position_mm, direction, conditions, offset_mm=150.0, pitch_urad=15.0, length_mm=350.0,
         center_mm=175.0):
    """Abbe error: the carriage's pitch angle times the offset between the laser beam and the
    functional point, on a bowed guideway.

    Parameters
    ----------
    position_mm : array-like
        Target position x [mm].
    offset_mm : float
        Abbe offset [mm].
    pitch_urad : float
        Pitch angle at the ends of the bow eps_0 [urad].
    length_mm, center_mm : float
        Length L and centre c of the bow [mm].

    Returns
    -------
    e : ndarray
        e = offset * eps(x) / 1000 [um] (mm * urad = nm), eps(x) = eps_0 (2 (x - c) / L)^2.

    References
    ----------
    Seed 000, eq. 17 (positioning error amplified by angular errors through the Abbe offset).
    """
    eps_urad = pitch_urad * (2 * (np.asarray(position_mm) - center_mm) / length_mm) ** 2
    return offset_mm * eps_urad / 1000.0


def dwell_settling(position_mm, direction, conditions, amplitude_um=1.0, tau_s=2.0):
    """Approach-dependent overshoot that settles during the dwell at the target.

    Parameters
    ----------
    direction : array-like
        Approach direction d (+1 or -1).
    conditions : dict
        ``dwell_s``: dwell at the target before the reading t_d [s].
    amplitude_um : float
        Overshoot at zero dwell A [um].
    tau_s : float
        Settling time constant tau [s].

    Returns
    -------
    e : ndarray
        e = d A exp(-t_d / tau) [um].

    References
    ----------
    ISO 230-2:2014, section 5.3 (dwell at each target); first-order settling of the position
    loop.
    """
    return (np.asarray(direction) * amplitude_um
            * np.exp(-np.asarray(conditions["dwell_s"]) / tau_s))


# ------------------------------------------------------------------------------ records
@dataclass(frozen=True)
class Effect:
    """Everything the product knows about one named effect (see the module docstring)."""

    name: str
    function: Callable
    kind: str                      # 'lost_motion' or 'position'
    unit: str                      # unit of the amplitude
    amplitude: str                 # the amplitude parameter (linear in the output)
    plausible: tuple[float, float]
    nuisance: dict = field(default_factory=dict)   # parameter -> grid
    inputs: tuple[str, ...] = ()   # readings / feature-table columns it depends on
    reference: str = ""
    separating_test: str = ""
    reading: str = ""
    defaults: dict = field(default_factory=dict)


def _defaults(function) -> dict:
    return {k: v.default for k, v in inspect.signature(function).parameters.items()
            if v.default is not v.empty}


def _record(function, **fields) -> Effect:
    return Effect(name=function.__name__, function=function, defaults=_defaults(function),
                  **fields)



EFFECTS: dict[str, Effect] = {r.name: r for r in (
    _record(backlash, kind="lost_motion", unit="um", amplitude="b0_um", plausible=(0.0, 50.0),
            inputs=(), reference=BACKLASH_PAPER,
            separating_test="compare linear and pendulum tests, or repeat with the indicator "
                            "at the nut",
            reading="a constant clearance between motor and table that every reversal has to "
                    "take up"),
    _record(backlash_position, kind="lost_motion", unit="um", amplitude="amplitude_um",
            plausible=(-20.0, 20.0), nuisance={"center_mm": "targets"}, inputs=("target",),
            reference=BACKLASH_PAPER,
            separating_test="measure the reversal value at more targets along the travel",
            reading="the clearance changes along the axis: screw and nut are worn where the "
                    "axis works most"),
    _record(backlash_feed, kind="lost_motion", unit="um per m/min", amplitude="k_um_per_m_min",
            plausible=(-10.0, 10.0), inputs=("feed_mm_min",), reference=BACKLASH_PAPER,
            separating_test="repeat at several feed rates",
            reading="friction grows with speed and winds up the drive's axial stiffness, so "
                    "the lost motion grows with feed"),
    _record(backlash_temperature, kind="lost_motion", unit="um/K", amplitude="k_um_per_k",
            plausible=(-3.0, 3.0), inputs=("machine_temp_c",), reference=BACKLASH_PAPER,
            separating_test="repeat at a different machine temperature",
            reading="the ball nut's preload changes with screw temperature and with it the "
                    "clearance"),
    _record(lead_error_linear, kind="position", unit="um/m", amplitude="k_um_per_m",
            plausible=(-200.0, 200.0), inputs=("target",), reference="ISO 230-2:2014; [Mechta2022]",
            separating_test="repeat at a different machine temperature and air state",
            reading="the screw's lead (or the scale) is off by a constant ratio, so the error "
                    "grows in proportion to position"),
    _record(lead_error_periodic, kind="position", unit="um", amplitude="amplitude_um",
            plausible=(0.05, 10.0), nuisance={"pitch_mm": ("period", 4.0, 20.0),
                                              "phase_rad": "quadrature"},
            inputs=("target",), reference="ISO 230-2:2014, section 4.3",
            separating_test="use ISO irregular target spacing, or targets finer than half the "
                            "pitch",
            reading="the screw's lead varies within each turn: an error that repeats with the "
                    "screw pitch"),
    _record(lead_error_profile, kind="position", unit="um", amplitude="peak_um",
            plausible=(0.0, 100.0),
            nuisance={"n_control": "per_target", "start_mm": "start", "stop_mm": "stop"},
            inputs=("target",), reference=ERROR_MODELS,
            separating_test="measure pitch and yaw along the axis (an Abbe error has the same "
                            "shape along one line), or repeat at more targets",
            reading="a smooth non-linear positioning error along the axis, what a pitch-error "
                    "compensation table corrects (backlash compensate)"),
    _record(thermal_expansion, kind="position", unit="um/(m K)", amplitude="alpha_um_per_m_k",
            plausible=(5.0, 25.0), nuisance={"x_fixed_mm": "ends"},
            inputs=("target", "machine_temp_c"),
            reference="ISO 230-3; ISO 1",
            separating_test="repeat the test at a different machine temperature",
            reading="the screw expands from its fixed bearing as it warms"),
    _record(thermal_drift, kind="position", unit="um", amplitude="amplitude_um",
            plausible=(-30.0, 30.0), nuisance={"tau_s": tuple(np.geomspace(120.0, 7200.0, 12))},
            inputs=("measured_at",), reference="ISO 230-3, thermal drift test",
            separating_test="repeat after a warm-up, or log time and temperature along the run",
            reading="the axis drifts during the run as the machine warms up"),
    _record(air_refraction, kind="position", unit="", amplitude="fraction",
            plausible=(0.3, 1.6), inputs=("target", "ambient_temp_c", "pressure_hpa",
                                          "humidity_pct"),
            reference="Edlen (1966); Birch and Downs (1993)",
            separating_test="repeat under a different air pressure or temperature, or check the "
                            "laser's air compensation",
            reading="the laser's wavelength in air is not compensated for the air's state"),
    _record(abbe, kind="position", unit="urad at 150 mm offset", amplitude="pitch_urad",
            plausible=(-200.0, 200.0), nuisance={"length_mm": "travel", "center_mm": "middle"},
            inputs=("target",), reference="[Mechta2022], eq. 17",
            separating_test="measure the carriage's pitch angle along the axis, or repeat with "
                            "a different Abbe offset",
            reading="the carriage pitches along a bowed guideway and the offset between beam "
                    "and tool turns the angle into a position error"),
    _record(dwell_settling, kind="position", unit="um", amplitude="amplitude_um",
            plausible=(-10.0, 10.0), nuisance={"tau_s": tuple(np.geomspace(0.5, 20.0, 10))},
            inputs=("direction", "dwell_s"), reference="ISO 230-2:2014, section 5.3",
            separating_test="repeat with several (at least three) dwell times",
            reading="the position loop overshoots against the approach and settles during the "
                    "dwell"),
    _record(reversal_profile, kind="position", unit="um", amplitude="peak_um",
            plausible=(0.0, 100.0),
            nuisance={"n_control": "per_target", "start_mm": "start", "stop_mm": "stop"},
            inputs=("target", "direction"), reference=ERROR_MODELS + "; ISO 230-2:2014",
            separating_test="a clearance b(x) >= 0 gives a reversal value of one sign at every "
                            "target: measure the reversal value at more targets (a sign change "
                            "along the axis is not lost motion), or measure pitch along the "
                            "axis in both directions",
            reading="the error depends on the direction of approach and changes along the "
                    "axis, of either sign (the carriage pitches differently each way, or the "
                    "screw's hysteresis varies along it): what separate forward and reverse "
                    "compensation tables correct (backlash compensate)"),
)}



def _derive() -> None:
    """The views read from ``EFFECTS``, computed again whenever a record comes or goes."""
    global EFFECT_NAMES, LOST_MOTION, DEFAULTS
    # The vocabulary (docs/data-contract.md, section 4, with ``schema.NO_EFFECT``).
    EFFECT_NAMES = tuple(EFFECTS)
    LOST_MOTION = tuple(name for name, r in EFFECTS.items() if r.kind == "lost_motion")
    DEFAULTS = {name: dict(r.defaults) for name, r in EFFECTS.items()}


_derive()


def register(function: Callable, **fields) -> Effect:
    """Add an effect from outside this module: ``function`` and the fields of its ``Effect``
    record (``kind``, ``unit``, ``amplitude``, ``plausible``...), as the records above are
    made. The twin, the effect model, ``discover`` and the docs' table read it from then on.

    Raises
    ------
    ValueError
        When an effect of that name exists already.
    """
    record = _record(function, **fields)
    if record.name in EFFECTS:
        raise ValueError(f"effect {record.name!r} exists already")
    EFFECTS[record.name] = record
    _derive()
    return record


def unregister(name: str) -> None:
    """Remove effect ``name`` (one added by ``register``)."""
    del EFFECTS[name]
    _derive()


def effects_table() -> str:
    """The docs' table of effects (``docs/data-contract.md``, section 4, filled in by
    ``docs/hooks.py`` as the site is built): every record, then the verdict ``none``."""
    rows = ["| name | kind | amplitude [unit] | what it describes | what separates it |",
            "|---|---|---|---|---|"]
    rows += [f"| `{r.name}` | {r.kind.replace('_', ' ')} | `{r.amplitude}` [{r.unit or '-'}] | "
             f"{r.reading} | {r.separating_test} |" for r in EFFECTS.values()]
    rows.append("| `none` | | | the verdict that no effect is missing | |")
    return "\n".join(row.replace("*", r"\*") for row in rows) + "\n"


def contribution(name: str, position_mm, direction, conditions, **params) -> np.ndarray:
    """The named effect with its defaults overridden by ``params`` [um]."""
    record = EFFECTS[name]
    return np.asarray(record.function(position_mm, direction, conditions,
                                      **{**record.defaults, **params}), float)


def lost_motion_um(enabled: dict, position_mm, conditions) -> np.ndarray:
    """Play width b [um]: the sum of the enabled lost-motion effects, never negative."""
    b = np.zeros(np.shape(position_mm))
    for name, params in enabled.items():
        if name in LOST_MOTION:
            b = b + contribution(name, position_mm, 0, conditions, **params)
    return np.maximum(b, 0.0)
