"""Siemens SINUMERIK: EEC table (``%_N_AX_EEC_INI``) and ``MD32450 BACKLASH``.

EEC (leadscrew/encoder error compensation, function manual K3): ``$AA_ENC_COMP[0,N,AXn]`` is
the error [mm] (deg for a rotary axis) at interpolation point N of encoder 0, points equidistant
from ``$AA_ENC_COMP_MIN`` by ``$AA_ENC_COMP_STEP`` to ``$AA_ENC_COMP_MAX``, the file ending with
``M17``; the control interpolates linearly, keeps the first and last values active outside the
table, and the value at the reference point is 0. One table serves both directions, so it
holds the bidirectional mean error; the reversal goes to MD32450 [mm] (deg).
MD38000 ``MM_ENC_COMP_MAX_POINTS`` must be at least the number of points, and the table is
activated with MD32700 ``ENC_COMP_ENABLE`` (machine builder).
Sign (K3, 4.4.2.1): the control modifies the position actual value by the compensation value,
and "a positive compensation value causes the corresponding machine axis to move in the negative
direction", so the value is the measured error; the table should be 0 at the reference point.
Modulo (K3, 4.4.2.2, ``$AA_ENC_COMP_IS_MODULO``): with the modulo function the table repeats
cyclically, the value at ``_MAX`` followed at once by the value at ``_MIN``; for a 360 deg modulo
rotary axis the manual suggests ``_MIN`` 0 deg and ``_MAX`` 360 deg, with the same value at both
(else the compensation jumps there). So a rotary axis whose targets cover a whole turn
(``common.full_turn``) gets ``_IS_MODULO=1`` and a table from its start to start + 360 deg,
the closing step interpolated from the last target to the first and the value at ``_MAX`` that
at ``_MIN``; a partial turn and a linear axis get ``_IS_MODULO=0`` and the measured range.
Not confirmed against the manual: the ``$MA_BACKLASH[0,AXn]`` assignment syntax of the
machine-data file, and a modulo table whose range differs from the axis's modulo range
(MD30330 ``MODULO_RANGE``; the table written starts at the first target or below it).
"""

from __future__ import annotations

from features.readings.fileio import write_text
from pipeline.compensation.common import (
    AXIS_INDEX,
    error_table,
    header,
    reference_position,
    table_sign,
    units,
)

MAX_POINTS = 2000
BACKLASH_SYNTAX = "$MA_BACKLASH[0,AXn] syntax of the machine-data file"
MODULO_RANGE = ("a modulo table whose _MIN differs from the axis's MD30340 MODULO_RANGE_START "
                "(the table is taken to repeat from _MIN)")


def write(profile, out_dir, options) -> dict:
    axis = f"AX{AXIS_INDEX[profile.axis] + 1}"
    points, error, interp_error, modulo = error_table(profile, options.spacing_mm, MAX_POINTS)
    ref = reference_position(points, options.reference_mm)
    error = (error - error[points == ref][0]) / profile.scale  # 0 at the reference point
    factor, sign = table_sign("error", options)
    error = factor * error
    step = points[1] - points[0] if len(points) > 1 else 1.0
    unconfirmed = [BACKLASH_SYNTAX, *([MODULO_RANGE] if modulo else [])]
    pos, dev = units(profile)
    head = header(profile, "SINUMERIK EEC", ";", [
        (f"$AA_ENC_COMP = bidirectional mean error (measured - nominal) [{pos}], 0 at the "
        f"reference point {ref:g} {pos} (a positive value moves the axis negative); machine "
        f"axis {axis}") if sign == "error" else
        (f"$AA_ENC_COMP = bidirectional mean correction (nominal - measured) [{pos}], 0 at "
         f"the reference point {ref:g} {pos} (the site's sign convention, not the manual's); machine "
         f"axis {axis}"),
        (f"{len(points)} points every {step:g} {pos}; linear interpolation error at the "
        f"measured targets {interp_error:.4f} {dev}; needs MD38000 MM_ENC_COMP_MAX_POINTS >= {len(points)}"),
        *_modulo_lines(modulo, points),
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    lines = ["%_N_AX_EEC_INI", "CHANDATA(1)", head.rstrip("\n")]  # %_N_ must be line 1
    lines += [f"$AA_ENC_COMP[0,{i},{axis}]={v:.6f}" for i, v in enumerate(error)]
    lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={step:.6f}",
              f"$AA_ENC_COMP_MIN[0,{axis}]={points[0]:.6f}",
              f"$AA_ENC_COMP_MAX[0,{axis}]={points[-1]:.6f}",
              f"$AA_ENC_COMP_IS_MODULO[0,{axis}]={int(modulo)}", "M17"]
    eec = write_text(out_dir / f"{profile.stem}_AX_EEC.INI", "\n".join(lines) + "\n")
    md = write_text(out_dir / f"{profile.stem}_MD32450.INI", header(
        profile, "SINUMERIK machine data", ";",
        [f"MD32450 BACKLASH [{pos}]: mean lost motion, added at every reversal",
         f"NOT CONFIRMED: {BACKLASH_SYNTAX}"])
        + f"$MA_BACKLASH[0,{axis}]={profile.backlash / profile.scale:.6f}\nM17\n")
    return {"files": {"table": eec, "parameters": md}, "interpolation_error_um": interp_error,
            "points": len(points), "spacing_mm": float(step),
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign}


def _modulo_lines(modulo: bool, points) -> list[str]:
    """Comment lines of a modulo table (one turn): what repeats, and the axis it needs."""
    if not modulo:
        return []
    return [(f"$AA_ENC_COMP_IS_MODULO=1: the table covers one turn, {points[0]:g} to "
             f"{points[-1]:g} deg, and repeats cyclically; the value at _MAX is the value at "
             "_MIN (K3, 4.4.2.2)"),
            "for a modulo rotary axis (MD30310 ROT_IS_MODULO=1, MD30330 MODULO_RANGE = 360 deg)"]
