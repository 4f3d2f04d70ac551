"""Fanuc: parameter 1851 (backlash) and pitch-error compensation (parameters 3620-3624).

1851: backlash compensating value per axis, detection units, -9999..+9999 (parameter manual,
e.g. 0i-C B-64120EN). Pitch error: equidistant compensation points every 3624 detection units,
numbered so that point 3620 is the reference position, 3621/3622 the most negative / positive
point numbers, 3623 the magnification; the value of point N is the *increment* output over the
section from point N-1 to N (parameter manual 0i-PB B-63980EN), in detection units times 3623.
The values here are corrections (what the control adds: -error), one set for both directions
(bidirectional pitch-error compensation, 3605#0, is not written); the reversal goes to 1851.
Written as a parameter sheet (``NNNN AXIS = value``, ``PITCH n = value``) for entry at the
control or conversion by the machine builder's tool, not as a punched-tape file.
Not confirmed: the sign of the pitch-error values, the value range per point (checked here as
-127..127 after magnification) and how the control distributes an increment within its section
(the twin's controller model interpolates linearly).
"""

from __future__ import annotations

import numpy as np

from features.readings.errors import InputError
from features.readings.fileio import write_text
from pipeline.compensation.common import header, reference_position, table_sign
from pipeline.compensation.profile import grid, resample

MAX_POINTS = 1024
FIRST_POINT = 1
VALUE_LIMIT = 127
SIGN_TEXT = {"correction": "corrections, -error", "error": "errors, the site's convention"}


def write(profile, out_dir, options) -> dict:
    unit_um = options.fanuc_unit_um
    if not unit_um > 0:
        raise InputError("must be > 0", parameter="fanuc_unit_um")
    points = grid(profile.target, options.spacing_mm, MAX_POINTS)
    error, interp_error = resample(profile.target, profile.position_error, points)
    ref = reference_position(points, options.reference_mm)
    ref_index = int(np.flatnonzero(points == ref)[0])
    factor, sign = table_sign("correction", options)
    correction = -factor * (error - error[ref_index])              # [um], 0 at the reference
    cumulative = np.round(correction / unit_um).astype(int)        # detection units
    increment = np.r_[0, np.diff(cumulative)]
    magnification = max(1, int(np.ceil(np.max(np.abs(increment)) / VALUE_LIMIT)))
    values = np.round(increment / magnification).astype(int)
    rebuilt = np.cumsum(np.r_[0, values[1:]]) * magnification
    rebuilt -= rebuilt[ref_index]
    quantisation = float(np.max(np.abs(rebuilt * unit_um - correction)))
    step_mm = points[1] - points[0] if len(points) > 1 else 0
    interval = step_mm * 1000.0 / unit_um if len(points) > 1 else 1.0
    backlash_units = round(profile.backlash / profile.scale * 1000.0 / unit_um)
    if abs(backlash_units) > 9999:
        raise InputError(f"backlash {backlash_units} detection units exceeds 1851's 9999; "
                         "choose a coarser detection unit", parameter="fanuc_unit_um")
    numbers = FIRST_POINT + np.arange(len(points))
    ref_number = int(numbers[ref_index])
    unconfirmed = [f"sign of the pitch-error values (written as {SIGN_TEXT[sign]})",
                   f"value range per point (checked as -{VALUE_LIMIT}..{VALUE_LIMIT})",
                   "distribution of an increment within its section"]
    a = profile.axis
    head = header(profile, "FANUC", ";", [
        (f"detection unit {unit_um:g} um; interval {step_mm:g} mm; interpolation error at the "
         f"measured targets {interp_error:.4f} um, rounding to detection units "
         f"{quantisation:.4f} um"),
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    body = [f"DETECTION UNIT = {unit_um:g} um",
            f"REFERENCE POSITION = {ref:.4f} mm",
            f"1851 {a} = {backlash_units}    ; backlash compensating value [detection units]",
            f"3620 {a} = {ref_number}    ; point number of the reference position",
            f"3621 {a} = {numbers[0]}    ; most negative point number",
            f"3622 {a} = {numbers[-1]}    ; most positive point number",
            f"3623 {a} = {magnification}    ; magnification",
            f"3624 {a} = {round(interval)}    ; point interval [detection units]",
            "; pitch error compensation: increment over the section ending at each point"]
    body += [f"PITCH {n} = {v}" for n, v in zip(numbers, values)]
    sheet = write_text(out_dir / f"{profile.stem}_fanuc.txt", head + "\n".join(body) + "\n")
    return {"files": {"parameters": sheet}, "interpolation_error_um": interp_error,
            "quantisation_error_um": quantisation, "points": len(points),
            "spacing_mm": float(points[1] - points[0]) if len(points) > 1 else None,
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign}
