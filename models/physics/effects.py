"""Named physical effects of a ball-screw feed axis, one record each (docs/data-contract.md §4).

Every effect is a pure function of arrays, in the manner of pvlib: inputs with units in their
names, parameters with physically plausible defaults (``DEFAULTS``), output in um.

Two kinds:

- **lost motion** (``LOST_MOTION``): the width b [um] of the play between motor and table. The
  axis model (``models.physics.axis``) runs the commanded path through a play operator of that
  width; b is the sum of the enabled lost-motion effects.
- **position errors** (all others): the laser reading minus the true target position [um],
  added to every reading.

Conditions are arrays aligned with the positions: ``feed_mm_min``, ``dwell_s``,
``machine_temp_c``, ``ambient_temp_c``, ``pressure_hpa``, ``humidity_pct`` and ``elapsed_s``
(time since the start of the run). ``direction`` is +1 or -1 (approach direction).
"""

from __future__ import annotations

import inspect

import numpy as np

REFERENCE_TEMP_C = 20.0
REFERENCE_PRESSURE_HPA = 1013.25
REFERENCE_HUMIDITY_PCT = 50.0
# Edlen sensitivities of the air's refractive index near 20 degC, 1013 hPa, 50 %RH [ppm per unit]
EDLEN_PPM_PER_K = -0.93
EDLEN_PPM_PER_HPA = 0.27
EDLEN_PPM_PER_PCT = -0.0085
STEEL_ALPHA_UM_PER_M_K = 11.5


def backlash(position_mm, direction, conditions, b0_um=2.0):
    """Constant lost motion b = b0 [um] (seed 004, section 2.2.2)."""
    return np.broadcast_to(np.asarray(b0_um, float), np.shape(position_mm))


def backlash_position(position_mm, direction, conditions, amplitude_um=1.0, center_mm=175.0,
                      width_mm=80.0):
    """Local wear of screw and nut where the axis works most: a Gaussian bump
    b = A exp(-((x - c) / w)^2) [um]."""
    return amplitude_um * np.exp(-((np.asarray(position_mm) - center_mm) / width_mm) ** 2)


def backlash_feed(position_mm, direction, conditions, k_um_per_m_min=1.0):
    """Friction windup: the drive's friction grows with speed and winds up the axial stiffness,
    b = k * feed / 1000 [um] with feed in mm/min (k in um per m/min)."""
    return k_um_per_m_min * np.asarray(conditions["feed_mm_min"]) / 1000.0


def backlash_temperature(position_mm, direction, conditions, k_um_per_k=-0.3):
    """Ball-nut preload changes with screw temperature: b = k (T_machine - 20 degC) [um];
    negative k: a warmer nut expands onto the balls and closes the clearance."""
    return k_um_per_k * (np.asarray(conditions["machine_temp_c"]) - REFERENCE_TEMP_C)


def lead_error_linear(position_mm, direction, conditions, k_um_per_m=8.0):
    """Cumulative lead (or scale) error proportional to position: e = k x / 1000 [um]."""
    return k_um_per_m * np.asarray(position_mm) / 1000.0


def lead_error_periodic(position_mm, direction, conditions, amplitude_um=1.0, pitch_mm=10.0,
                        phase_rad=0.0):
    """Periodic lead error of the screw, period = pitch: e = A sin(2 pi x / p + phi) [um].
    Invisible when targets are spaced at multiples of the pitch (ISO 230-2 irregular spacing)."""
    return amplitude_um * np.sin(2 * np.pi * np.asarray(position_mm) / pitch_mm + phase_rad)


def thermal_expansion(position_mm, direction, conditions, alpha_um_per_m_k=STEEL_ALPHA_UM_PER_M_K,
                      x_fixed_mm=0.0):
    """Screw expansion from its fixed bearing: e = alpha (T_machine - 20) (x - x_fixed) / 1000
    [um], alpha of steel 11.5 um/(m K)."""
    dT = np.asarray(conditions["machine_temp_c"]) - REFERENCE_TEMP_C
    return alpha_um_per_m_k * dT * (np.asarray(position_mm) - x_fixed_mm) / 1000.0


def thermal_drift(position_mm, direction, conditions, amplitude_um=2.0, tau_s=900.0):
    """Warm-up drift during a run: e = A (1 - exp(-t / tau)) [um], t = time since run start."""
    return amplitude_um * (1.0 - np.exp(-np.asarray(conditions["elapsed_s"]) / tau_s))


def edlen_ppm(conditions):
    """Refractive-index change of air from its reference state [ppm] (linearised Edlen)."""
    return (EDLEN_PPM_PER_K * (np.asarray(conditions["ambient_temp_c"]) - REFERENCE_TEMP_C)
            + EDLEN_PPM_PER_HPA * (np.asarray(conditions["pressure_hpa"]) - REFERENCE_PRESSURE_HPA)
            + EDLEN_PPM_PER_PCT * (np.asarray(conditions["humidity_pct"])
                                   - REFERENCE_HUMIDITY_PCT))


def air_refraction(position_mm, direction, conditions, fraction=1.0):
    """Uncompensated air refraction of the laser: the wavelength in air changes by the Edlen
    index change, e = fraction * ppm * x / 1000 [um] (1 ppm of 1 m is 1 um); fraction 1 means
    no compensation at all."""
    return fraction * edlen_ppm(conditions) * np.asarray(position_mm) / 1000.0


def abbe(position_mm, direction, conditions, offset_mm=150.0, pitch_urad=15.0, length_mm=350.0):
    """Abbe error (seed 001): the carriage's pitch angle times the offset between the laser
    beam and the functional point, e = offset * eps(x) / 1000 [um] (mm * urad = nm), with a
    bowed guideway eps(x) = pitch * (2 (x - L/2) / L)^2 [urad]."""
    eps_urad = pitch_urad * (2 * (np.asarray(position_mm) - length_mm / 2) / length_mm) ** 2
    return offset_mm * eps_urad / 1000.0


def dwell_settling(position_mm, direction, conditions, amplitude_um=1.0, tau_s=2.0):
    """Approach-dependent overshoot that settles during the dwell at the target:
    e = d A exp(-dwell / tau) [um], d the approach direction (+1 or -1)."""
    return (np.asarray(direction) * amplitude_um
            * np.exp(-np.asarray(conditions["dwell_s"]) / tau_s))


EFFECTS = {f.__name__: f for f in (
    backlash, backlash_position, backlash_feed, backlash_temperature, lead_error_linear,
    lead_error_periodic, thermal_expansion, thermal_drift, air_refraction, abbe, dwell_settling)}
LOST_MOTION = ("backlash", "backlash_position", "backlash_feed", "backlash_temperature")
# Named parameter sets: the defaults of each effect.
DEFAULTS = {name: {k: v.default for k, v in inspect.signature(f).parameters.items()
                   if v.default is not v.empty} for name, f in EFFECTS.items()}
# Conditions each effect reads (beyond position and direction).
NEEDS = {"backlash_feed": ("feed_mm_min",), "backlash_temperature": ("machine_temp_c",),
         "thermal_expansion": ("machine_temp_c",), "thermal_drift": ("elapsed_s",),
         "air_refraction": ("ambient_temp_c", "pressure_hpa", "humidity_pct"),
         "dwell_settling": ("dwell_s",)}


def contribution(name: str, position_mm, direction, conditions, **params) -> np.ndarray:
    """The named effect with its defaults overridden by ``params`` [um]."""
    return np.asarray(EFFECTS[name](position_mm, direction, conditions,
                                    **{**DEFAULTS[name], **params}), float)


def lost_motion_um(enabled: dict, position_mm, conditions) -> np.ndarray:
    """Play width b [um]: the sum of the enabled lost-motion effects, never negative."""
    b = np.zeros(np.shape(position_mm))
    for name, params in enabled.items():
        if name in LOST_MOTION:
            b = b + contribution(name, position_mm, 0, conditions, **params)
    return np.maximum(b, 0.0)
