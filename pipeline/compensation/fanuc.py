"""Fanuc: parameter 1851 (backlash) and pitch-error compensation (parameters 3620-3625).

1851: backlash compensating value per axis, detection units, -9999..+9999 (parameter manual,
e.g. 0i-C B-64120EN). Pitch error: equidistant compensation points every 3624 detection units,
numbered so that point 3620 is the reference position, 3621/3622 the most negative / positive
point numbers, 3623 the magnification; the value of point N is the *increment* output over the
section from point N-1 to N (parameter manual 0i-PB B-63980EN), in detection units times 3623.
The values here are corrections (what the control adds: -error), one set for both directions;
the reversal goes to 1851. Written as a parameter sheet (``NNNN AXIS = value``, ``PITCH n =
value``) for entry at the control or conversion by the machine builder's tool, not as a
punched-tape file.

Rotary axes: positions and the detection unit in degrees (``fanuc_unit_um`` thousandths of the
position unit: 1 um on a linear axis, 0.001 deg on a rotary one), deviations in arcsec. A rotary
axis measured over a whole turn (``common.full_turn``) gets the rotary-axis type table of the
0i-PB parameter manual (B-63980EN, description of 3620-3625, example 2): 3625 the movement per
rotation (360 deg in detection units), the table starting at the reference position (3621 =
3620) and ending one rotation later (3622 = 3620 + 3625 / 3624), the values of one rotation
summing to 0 (else the error accumulates turn after turn) and the reference point holding the
value of the last point. A partial-turn rotary axis gets the linear-type table in degrees.

Not written: bidirectional pitch error compensation (3605#0 BDPx; 3626 the most negative point
of the negative-direction table, 3627 the value at the reference position approached against
the reference-return direction: FANUC Series 16i/18i technical report A-77810E, parameter
table). The public copy does not say how 3627 and 1851 combine with the negative-direction
values, so the sheet keeps one table and 1851 and the result reports the reversal left.
Not confirmed: the sign of the pitch-error values, the value range per point (checked here as
-127..127 after magnification) and how the control distributes an increment within its section
(the twin's controller model interpolates linearly).
"""

from __future__ import annotations

import numpy as np

from features.readings.errors import InputError
from features.readings.fileio import write_text
from pipeline.compensation.common import (
    TURN_DEG,
    error_table,
    header,
    reference_position,
    resample_turn,
    table_sign,
    units,
)

MAX_POINTS = 1024
FIRST_POINT = 1
VALUE_LIMIT = 127
SIGN_TEXT = {"correction": "corrections, -error", "error": "errors, the site's convention"}


def write(profile, out_dir, options) -> dict:
    unit_um = options.fanuc_unit_um
    if not unit_um > 0:
        raise InputError("must be > 0", parameter="fanuc_unit_um")
    points, error, interp_error, rotary = error_table(profile, options.spacing_mm, MAX_POINTS)
    ref = reference_position(points, options.reference_mm)
    if rotary:  # the rotary-axis type table starts at the reference position
        points = ref + (points - points[0])
        error, interp_error = resample_turn(profile.target, profile.position_error, points)
    ref_index = int(np.flatnonzero(points == ref)[0])
    factor, sign = table_sign("correction", options)
    unit_dev = unit_um * (profile.scale / 1000.0)                 # [um, arcsec] per unit
    correction = -factor * (error - error[ref_index])             # [um, arcsec], 0 at the ref
    values, magnification = _increments(correction / unit_dev, rotary)
    rebuilt = np.cumsum(np.r_[0, values[1:]]) * magnification
    rebuilt -= rebuilt[ref_index]
    quantisation = float(np.max(np.abs(rebuilt * unit_dev - correction)))
    step = points[1] - points[0] if len(points) > 1 else 0
    interval = step * 1000.0 / unit_um if len(points) > 1 else 1.0
    backlash_units = round(profile.backlash / profile.scale * 1000.0 / unit_um)
    if abs(backlash_units) > 9999:
        raise InputError(f"backlash {backlash_units} detection units exceeds 1851's 9999; "
                         "choose a coarser detection unit", parameter="fanuc_unit_um")
    numbers = FIRST_POINT + np.arange(len(points))
    unconfirmed = [f"sign of the pitch-error values (written as {SIGN_TEXT[sign]})",
                   f"value range per point (checked as -{VALUE_LIMIT}..{VALUE_LIMIT})",
                   "distribution of an increment within its section"]
    a = profile.axis
    pos, dev = units(profile)
    unit, per = _unit(profile, unit_um)
    head = header(profile, "FANUC", ";", [
        (f"detection unit {unit}; interval {step:g} {pos}; interpolation error at the "
         f"measured targets {interp_error:.4f} {dev}, rounding to detection units "
         f"{quantisation:.4f} {dev}"),
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    body = [f"DETECTION UNIT = {unit}",
            f"REFERENCE POSITION = {ref:.4f} {pos}",
            f"1851 {a} = {backlash_units}    ; backlash compensating value [detection units{per}]",
            f"3620 {a} = {numbers[ref_index]}    ; point number of the reference position",
            f"3621 {a} = {numbers[0]}    ; most negative point number",
            f"3622 {a} = {numbers[-1]}    ; most positive point number",
            f"3623 {a} = {magnification}    ; magnification",
            f"3624 {a} = {round(interval)}    ; point interval [detection units{per}]",
            *_rotation_lines(a, rotary, unit_um, per, numbers),
            "; pitch error compensation: increment over the section ending at each point"]
    body += [f"PITCH {n} = {v}" for n, v in zip(numbers, values)]
    sheet = write_text(out_dir / f"{profile.stem}_fanuc.txt", head + "\n".join(body) + "\n")
    return {"files": {"parameters": sheet}, "interpolation_error_um": interp_error,
            "quantisation_error_um": quantisation, "points": len(points),
            "spacing_mm": float(step) if len(points) > 1 else None,
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign}


def _increments(cumulative_units, rotary: bool) -> tuple[np.ndarray, int]:
    """Pitch-error values (increment of each section, first point 0) of the cumulative
    correction [detection units], and the magnification 3623 that keeps them within
    +-VALUE_LIMIT. The values are increments of the cumulative correction rounded in units of
    the magnification, so the rounding does not drift along the axis (and the values of one
    rotation sum to 0). A rotary-axis table's first point (the reference) holds the value of its
    last point (0i-PB parameter manual, example 2)."""
    first = np.diff(np.round(cumulative_units).astype(int))
    magnification = max(1, int(np.ceil(np.max(np.abs(first), initial=0) / VALUE_LIMIT)))
    values = np.r_[0, np.diff(np.round(cumulative_units / magnification).astype(int))]
    if rotary:
        values[0] = values[-1]
    return values, magnification


def _unit(profile, unit_um: float) -> tuple[str, str]:
    """The detection unit as written (``1 um``; ``0.001 deg`` on a rotary axis) and the label
    of values counted in it (empty on a linear axis, `` of 0.001 deg`` on a rotary one)."""
    if units(profile)[0] == "mm":
        return f"{unit_um:g} um", ""
    return f"{unit_um / 1000:g} deg", f" of {unit_um / 1000:g} deg"


def _rotation_lines(a: str, rotary: bool, unit_um: float, per: str, numbers) -> list[str]:
    """3625 and a comment for a rotary-axis type table (one rotation), else nothing."""
    if not rotary:
        return []
    return [(f"3625 {a} = {round(TURN_DEG * 1000.0 / unit_um)}    ; movement per rotation "
             f"[detection units{per}]: rotary-axis type pitch error compensation"),
            (f"; one rotation from the reference position: point {numbers[0]} holds the value "
             f"of point {numbers[-1]}, the values of points {numbers[1]}..{numbers[-1]} sum to 0")]
