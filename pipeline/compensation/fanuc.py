"""Fanuc: parameter 1851 (backlash) and pitch-error compensation (parameters 3620-3627).

1851: backlash compensating value per axis, detection units, -9999..+9999 (parameter manual,
e.g. 0i-C B-64120EN). Pitch error: equidistant compensation points every 3624 detection units,
numbered so that point 3620 is the reference position, 3621/3622 the most negative / positive
point numbers, 3623 the magnification; the value of point N is the *increment* output over the
section from point N-1 to N (parameter manual 0i-PB B-63980EN), in detection units times 3623.
The values here are corrections (what the control adds: -error), one set for both directions
and the reversal in 1851, or one set per direction (below). Written as a parameter sheet
(``NNNN AXIS = value``, ``PITCH n = value``) for entry at the control or conversion by the
machine builder's tool, not as a punched-tape file.

Rotary axes: positions and the detection unit in degrees (``fanuc_unit_um`` thousandths of the
position unit: 1 um on a linear axis, 0.001 deg on a rotary one), deviations in arcsec. A rotary
axis measured over a whole turn (``common.full_turn``) gets the rotary-axis type table of the
0i-PB parameter manual (B-63980EN, description of 3620-3625, example 2): 3625 the movement per
rotation (360 deg in detection units), the table starting at the reference position (3621 =
3620) and ending one rotation later (3622 = 3620 + 3625 / 3624), the values of one rotation
summing to 0 (else the error accumulates turn after turn) and the reference point holding the
value of the last point. A partial-turn rotary axis gets the linear-type table in degrees.

Bidirectional pitch error compensation (FANUC Series 16i/18i-MA/TA technical report A-77810E,
table (a) of the setting data): 3605#0 BDPx enables it; 3621 / 3622 are then the most distant
points for travel in the positive direction, 3626 the most distant negative-side point for travel
in the negative direction, 3627 the compensation amount (absolute, not an increment) at the
reference position when it is reached against the reference-return direction. Written when the
profile's reversal varies along the axis by more than its uncertainty
(``common.direction_dependent``); otherwise the sheet keeps one table and 1851. The report's
public copy shows the parameter table only, so the sheet states what it assumes (NOT CONFIRMED
lines, ``BIDIRECTIONAL_ASSUMED``): the negative-direction points numbered 3626 ... 3626 + 3622 -
3621 at the positions of points 3621 ... 3622; 3627 the signed value of the negative-direction
table at the reference position in detection units, not multiplied by 3623; reference-position
return in the positive direction (1006#5 ZMI = 0), so the positive-direction table is 0 there;
1851 written 0, so that the two tables carry the whole reversal whether or not the control also
applies 1851 with them. The twin's controller model applies the sheet exactly so.
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
    direction_dependent,
    header,
    reference_position,
    resampled,
    table_points,
    table_sign,
    units,
)

MAX_POINTS = 1024
FIRST_POINT = 1
VALUE_LIMIT = 127
SIGN_TEXT = {"correction": "corrections, -error", "error": "errors, the site's convention"}


BIDIRECTIONAL_ASSUMED = [
    ("numbering of the - direction points (3626 to 3626 + 3622 - 3621, at the positions of "
     "points 3621 to 3622)"),
    ("3627 as the signed value of the - direction table at the reference position, in "
     "detection units, not multiplied by 3623"),
    ("reference position return in the + direction (1006#5 ZMI = 0): the + direction table is "
     "0 at the reference position"),
    ("whether the control applies 1851 with bidirectional tables (written 0: the tables carry "
     "the whole reversal either way)")]


def write(profile, out_dir, options) -> dict:
    unit_um = options.fanuc_unit_um
    if not unit_um > 0:
        raise InputError("must be > 0", parameter="fanuc_unit_um")
    both = direction_dependent(profile)
    points, tables, interp_error, rotary = _tables(profile, options, both)
    ref_index = int(np.flatnonzero(points == reference_position(points, options.reference_mm))[0])
    factor, sign = table_sign("correction", options)
    unit_dev = unit_um * (profile.scale / 1000.0)                 # [um, arcsec] per unit
    # corrections [detection units]; the + direction (or only) table is 0 at the reference
    cumulative = [-factor * (t - tables[0][ref_index]) / unit_dev for t in tables]
    at_ref = [0, *(round(float(c[ref_index])) for c in cumulative[1:])]   # 0 and 3627
    magnification = _magnification(cumulative)
    values = [_increments(c - r, magnification, rotary) for c, r in zip(cumulative, at_ref)]
    quantisation = max(float(np.max(np.abs(_rebuilt(v, magnification, ref_index) + r - c)))
                       for v, r, c in zip(values, at_ref, cumulative)) * unit_dev
    step = points[1] - points[0] if len(points) > 1 else 0
    interval = step * 1000.0 / unit_um if len(points) > 1 else 1.0
    backlash_units = 0 if both else round(profile.backlash / profile.scale * 1000.0 / unit_um)
    if abs(backlash_units) > 9999:
        raise InputError(f"backlash {backlash_units} detection units exceeds 1851's 9999; "
                         "choose a coarser detection unit", parameter="fanuc_unit_um")
    numbers = [FIRST_POINT + k * len(points) + np.arange(len(points)) for k in range(len(tables))]
    unconfirmed = [f"sign of the pitch-error values (written as {SIGN_TEXT[sign]})",
                   f"value range per point (checked as -{VALUE_LIMIT}..{VALUE_LIMIT})",
                   "distribution of an increment within its section",
                   *(BIDIRECTIONAL_ASSUMED if both else [])]
    a = profile.axis
    pos, dev = units(profile)
    unit, per = _unit(profile, unit_um)
    head = header(profile, "FANUC", ";", [
        (f"detection unit {unit}; interval {step:g} {pos}; interpolation error at the "
         f"measured targets {interp_error:.4f} {dev}, rounding to detection units "
         f"{quantisation:.4f} {dev}"),
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    travel = ", travel in the + direction" if both else ""
    body = [f"DETECTION UNIT = {unit}",
            f"REFERENCE POSITION = {points[ref_index]:.4f} {pos}",
            *([f"3605#0 {a} = 1    ; BDPx: bidirectional pitch error compensation"] if both
              else []),
            (f"1851 {a} = {backlash_units}    ; backlash compensating value [detection "
             f"units{per}]" + (": the two tables carry the reversal" if both else "")),
            f"3620 {a} = {numbers[0][ref_index]}    ; point number of the reference position",
            f"3621 {a} = {numbers[0][0]}    ; most negative point number{travel}",
            f"3622 {a} = {numbers[0][-1]}    ; most positive point number{travel}",
            f"3623 {a} = {magnification}    ; magnification",
            f"3624 {a} = {round(interval)}    ; point interval [detection units{per}]",
            *_rotation_lines(a, rotary, unit_um, per, numbers),
            *_minus_lines(a, per, numbers, at_ref)]
    for k, (n, v) in enumerate(zip(numbers, values)):
        body.append("; pitch error compensation"
                    + ((", travel in the - direction" if k else travel) if both else "")
                    + ": increment over the section ending at each point")
        body += [f"PITCH {i} = {x}" for i, x in zip(n, v)]
    sheet = write_text(out_dir / f"{profile.stem}_fanuc.txt", head + "\n".join(body) + "\n")
    return {"files": {"parameters": sheet}, "interpolation_error_um": interp_error,
            "quantisation_error_um": quantisation, "points": len(points),
            "spacing_mm": float(step) if len(points) > 1 else None,
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign,
            "per_direction": both}


def _tables(profile, options, both: bool) -> tuple[np.ndarray, list, float, bool]:
    """The table points [mm, deg], the error per table at them [um, arcsec] (the mean error
    moving + and moving -, or the bidirectional mean error), the largest interpolation error
    at the measured targets and whether the table is one rotation. Two tables share the point
    budget; a rotary-axis type table starts at the reference position."""
    points, rotary = table_points(profile, options.spacing_mm, MAX_POINTS // (2 if both else 1))
    if rotary:
        points = reference_position(points, options.reference_mm) + (points - points[0])
    series = (profile.mean_up, profile.mean_down) if both else (profile.position_error,)
    tables, errors = zip(*(resampled(profile, s, points, rotary) for s in series))
    return points, list(tables), max(errors), rotary


def _magnification(cumulatives) -> int:
    """3623: the smallest magnification that keeps every table's increments of its cumulative
    correction [detection units] within +-VALUE_LIMIT."""
    largest = max(np.max(np.abs(np.diff(np.round(c).astype(int))), initial=0)
                  for c in cumulatives)
    return max(1, int(np.ceil(largest / VALUE_LIMIT)))


def _increments(cumulative_units, magnification: int, rotary: bool) -> np.ndarray:
    """Pitch-error values (increment of each section, first point 0) of the cumulative
    correction [detection units]: increments of the cumulative correction rounded in units of
    the magnification, so the rounding does not drift along the axis (and the values of one
    rotation sum to 0). A rotary-axis table's first point (the reference) holds the value of its
    last point (0i-PB parameter manual, example 2)."""
    values = np.r_[0, np.diff(np.round(cumulative_units / magnification).astype(int))]
    if rotary:
        values[0] = values[-1]
    return values


def _rebuilt(values, magnification: int, ref_index: int) -> np.ndarray:
    """The cumulative correction [detection units] the control builds from the values, 0 at
    the reference point."""
    rebuilt = np.cumsum(np.r_[0, values[1:]]) * magnification
    return rebuilt - rebuilt[ref_index]


def _minus_lines(a: str, per: str, numbers, at_ref) -> list[str]:
    """3626 and 3627 of the - direction table, when there is one."""
    if len(numbers) < 2:
        return []
    minus = numbers[1]
    return [(f"3626 {a} = {minus[0]}    ; most negative point number, travel in the - direction "
             f"(points {minus[0]}..{minus[-1]} at the positions of {numbers[0][0]}.."
             f"{numbers[0][-1]})"),
            (f"3627 {a} = {at_ref[1]}    ; value at the reference position reached in the - "
             f"direction, against the reference return (+) [detection units{per}]")]


def _unit(profile, unit_um: float) -> tuple[str, str]:
    """The detection unit as written (``1 um``; ``0.001 deg`` on a rotary axis) and the label
    of values counted in it (empty on a linear axis, `` of 0.001 deg`` on a rotary one)."""
    if units(profile)[0] == "mm":
        return f"{unit_um:g} um", ""
    return f"{unit_um / 1000:g} deg", f" of {unit_um / 1000:g} deg"


def _rotation_lines(a: str, rotary: bool, unit_um: float, per: str, numbers) -> list[str]:
    """3625 and a comment per table for a rotary-axis type table (one rotation), else nothing."""
    if not rotary:
        return []
    return [(f"3625 {a} = {round(TURN_DEG * 1000.0 / unit_um)}    ; movement per rotation "
             f"[detection units{per}]: rotary-axis type pitch error compensation"),
            *(f"; one rotation from the reference position: point {n[0]} holds the value "
              f"of point {n[-1]}, the values of points {n[1]}..{n[-1]} sum to 0" for n in numbers)]
