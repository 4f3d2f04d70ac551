"""Scalar-only controllers: Marlin and RepRapFirmware ``M425``, grblHAL ``$160-$162``.

They add one backlash distance [mm] at every reversal, the same everywhere on the axis, so the
position-dependent part of the test (lead error, varying backlash) is not compensated; the
output says how much of the reversal varies along the axis.
- Marlin ``M425 [F<fade>] [S<smoothing mm>] [X|Y|Z<mm>]`` (marlinfw.org, M425; needs
  BACKLASH_COMPENSATION and BACKLASH_GCODE); ``F1`` applies it fully.
- RepRapFirmware ``M425 X|Y|Z...<mm> [S<multiplier>]`` (RRF 3.5 and later, Duet3D G-code
  reference): extra steps inserted after a reversal over at least S (default 10) times the
  backlash; S is left at its default.
- grblHAL ``$160``/``$161``/``$162`` = X/Y/Z backlash [mm] (needs a build with backlash
  compensation); NOT CONFIRMED against the settings reference of your build.
"""

from __future__ import annotations

import numpy as np

from features.readings.errors import InputError
from features.readings.fileio import write_text
from pipeline.compensation.common import header

LINEAR = ("X", "Y", "Z")


def _scalar(profile, controller: str) -> tuple[float, list[str]]:
    if profile.axis not in LINEAR:
        raise InputError(f"{controller} backlash compensation covers X, Y and Z only, not "
                         f"{profile.axis}", parameter="controller")
    spread = float(np.ptp(profile.reversal)) if len(profile.reversal) > 1 else 0.0
    return profile.backlash / profile.scale, [
        (f"scalar backlash = mean lost motion {profile.backlash:.3f} um; the reversal varies by "
        f"{spread:.3f} um along the axis and the position error is not compensated")]


def _result(path, profile, unconfirmed):
    return {"files": {"parameters": path}, "interpolation_error_um": None, "points": 0,
            "spacing_mm": None, "backlash": round(profile.backlash, 4),
            "unconfirmed": unconfirmed}


def write_marlin(profile, out_dir, options) -> dict:
    b, lines = _scalar(profile, "Marlin")
    text = header(profile, "Marlin M425", ";", lines) + (
        f"M425 {profile.axis}{b:.4f} ; backlash distance [mm]\nM425 F1 ; apply it fully\n")
    return _result(write_text(out_dir / f"{profile.stem}_marlin.gcode", text), profile, [])


def write_reprap(profile, out_dir, options) -> dict:
    b, lines = _scalar(profile, "RepRapFirmware")
    text = header(profile, "RepRapFirmware M425 (RRF 3.5 or later)", ";", lines) + (
        f"M425 {profile.axis}{b:.4f} ; backlash [mm]\n")
    return _result(write_text(out_dir / f"{profile.stem}_reprap.gcode", text), profile, [])


def write_grblhal(profile, out_dir, options) -> dict:
    b, lines = _scalar(profile, "grblHAL")
    unconfirmed = ["$160-$162 numbering of your grblHAL build"]
    setting = 160 + LINEAR.index(profile.axis)
    text = header(profile, "grblHAL", ";", [*lines, f"NOT CONFIRMED: {unconfirmed[0]}"]) + (
        f"${setting}={b:.4f}\n")
    return _result(write_text(out_dir / f"{profile.stem}_grblhal.txt", text), profile,
                   unconfirmed)
