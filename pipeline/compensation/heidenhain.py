"""Heidenhain TNC: reversal value (MP710 / MP750) and a ``.COM`` nonlinear axis-error table.

MP710.x (TNC 426/430 and iTNC 530): backlash outside the control loop (rotary encoder), the
value the control adds to or subtracts from the encoder signal after a reversal, -1..+1 mm;
positive backlash = the encoder is ahead of the table, traverse too short (TNC 426/430
technical manual, 6.4.1). MP750.x (iTNC 530): reversal error inside the control loop (linear
encoder), -9.9999..+9.9999 mm, with MP752.x its compensation time. Nonlinear axis-error
compensation (selected per axis in MP730) reads ``.COM`` tables assigned in a ``.CMA`` file,
at most 256 entries per table. Values are the error (as MP720's linear error: positive when the
travel is too long); one table for both directions, so it holds the bidirectional mean error.
Not confirmed: the column layout of the ``.COM`` file written here (``NR position error``
lines between a ``BEGIN``/``[END]`` frame: check it against the control's table editor before
loading), its spacing rules on your control, and the sign of the ``.COM`` values.

Rotary axes: positions, values and MP710 in degrees. The frame line names the unit: ``MM`` for
a linear axis, ``DEG`` for a rotary one (**not confirmed**: the public technical manuals show
the ``.COM`` columns, ``AXISPOS`` and the axis's column on the TNC 620 / MANUALplus 620
generation, but no unit keyword for a rotary axis's table; the file says so). A rotary axis
measured over a whole turn (``common.full_turn``) gets a table from its start to start +
360 deg with the same value at both ends; whether the control wraps the table is not confirmed
(the twin's model holds the end values outside it).
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

MAX_POINTS = 256
ROTARY_UNIT = "unit keyword DEG of a rotary axis's .COM table (a linear axis's is MM)"
SIGN_TEXT = {"error": "error (measured - nominal)",
             "correction": "correction (nominal - measured, the site's sign convention)"}


def write(profile, out_dir, options) -> dict:
    points, error, interp_error, _ = error_table(profile, options.spacing_mm, MAX_POINTS)
    ref = reference_position(points, options.reference_mm)
    factor, sign = table_sign("error", options)
    error = factor * (error - error[points == ref][0]) / profile.scale
    pos, dev = units(profile)
    unconfirmed = [".COM column layout", ".COM spacing rules", "sign of the .COM values (error)",
                   *([ROTARY_UNIT] if pos == "deg" else [])]
    a = profile.axis
    head = header(profile, "Heidenhain TNC", ";", [
        (f"{a} = F({a}): {SIGN_TEXT[sign]} [{pos}], 0 at {ref:g} {pos}; {len(points)} points; "
        f"interpolation error at the measured targets {interp_error:.4f} {dev}"),
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    body = [f"BEGIN {profile.stem}.COM {pos.upper()}", f"NR    {a}-POS           {a}-ERROR"]
    body += [f"{i:<5d} {x:+.4f} {v:+.5f}" for i, (x, v) in enumerate(zip(points, error))]
    body.append("[END]")
    com = write_text(out_dir / f"{profile.stem}.COM", head + "\n".join(body) + "\n")
    index = AXIS_INDEX[a]
    b_mm = profile.backlash / profile.scale
    mp = write_text(out_dir / f"{profile.stem}_heidenhain_MP.txt", header(
        profile, "Heidenhain TNC machine parameters", ";",
        [f"MP710: backlash with a rotary encoder (outside the control loop) [{pos}]",
         "MP750 (iTNC 530): reversal error with a linear encoder; use instead of MP710 then"])
        + f"MP710.{index} = {b_mm:+.4f}\n; MP750.{index} = {b_mm:+.4f}\n")
    return {"files": {"table": com, "parameters": mp}, "interpolation_error_um": interp_error,
            "points": len(points),
            "spacing_mm": float(points[1] - points[0]) if len(points) > 1 else None,
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign}
