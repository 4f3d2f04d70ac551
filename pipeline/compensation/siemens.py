"""Siemens SINUMERIK: EEC table (``%_N_AX_EEC_INI``) and ``MD32450 BACKLASH``.

EEC (leadscrew/encoder error compensation, function manual K3): ``$AA_ENC_COMP[0,N,AXn]`` is
the error [mm] at interpolation point N of encoder 0, points equidistant from
``$AA_ENC_COMP_MIN`` by ``$AA_ENC_COMP_STEP`` to ``$AA_ENC_COMP_MAX``, not modulo, the file
ending with ``M17``; the control interpolates linearly, keeps the first and last values active
outside the table, and the value at the reference point is 0. One table serves both
directions, so it holds the bidirectional mean error; the reversal goes to MD32450 [mm].
MD38000 ``MM_ENC_COMP_MAX_POINTS`` must be at least the number of points, and the table is
activated with MD32700 ``ENC_COMP_ENABLE`` (machine builder).
Sign (K3, 4.4.2.1): the control modifies the position actual value by the compensation value,
and "a positive compensation value causes the corresponding machine axis to move in the negative
direction", so the value is the measured error; the table should be 0 at the reference point.
Not confirmed against the manual: the ``$MA_BACKLASH[0,AXn]`` assignment syntax of the
machine-data file.
"""

from __future__ import annotations

from features.readings.fileio import write_text
from pipeline.compensation.common import AXIS_INDEX, header, reference_position, table_sign, units
from pipeline.compensation.profile import grid, resample

MAX_POINTS = 2000


def write(profile, out_dir, options) -> dict:
    axis = f"AX{AXIS_INDEX[profile.axis] + 1}"
    points = grid(profile.target, options.spacing_mm, MAX_POINTS)
    error, interp_error = resample(profile.target, profile.position_error, points)
    ref = reference_position(points, options.reference_mm)
    error = (error - error[points == ref][0]) / profile.scale  # 0 at the reference point
    factor, sign = table_sign("error", options)
    error = factor * error
    step = points[1] - points[0] if len(points) > 1 else 1.0
    unconfirmed = ["$MA_BACKLASH[0,AXn] syntax of the machine-data file"]
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
        *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
    lines = ["%_N_AX_EEC_INI", "CHANDATA(1)", head.rstrip("\n")]  # %_N_ must be line 1
    lines += [f"$AA_ENC_COMP[0,{i},{axis}]={v:.6f}" for i, v in enumerate(error)]
    lines += [f"$AA_ENC_COMP_STEP[0,{axis}]={step:.6f}",
              f"$AA_ENC_COMP_MIN[0,{axis}]={points[0]:.6f}",
              f"$AA_ENC_COMP_MAX[0,{axis}]={points[-1]:.6f}",
              f"$AA_ENC_COMP_IS_MODULO[0,{axis}]=0", "M17"]
    eec = write_text(out_dir / f"{profile.stem}_AX_EEC.INI", "\n".join(lines) + "\n")
    md = write_text(out_dir / f"{profile.stem}_MD32450.INI", header(
        profile, "SINUMERIK machine data", ";",
        [f"MD32450 BACKLASH [{pos}]: mean lost motion, added at every reversal",
         *(f"NOT CONFIRMED: {u}" for u in unconfirmed)])
        + f"$MA_BACKLASH[0,{axis}]={profile.backlash / profile.scale:.6f}\nM17\n")
    return {"files": {"table": eec, "parameters": md}, "interpolation_error_um": interp_error,
            "points": len(points), "spacing_mm": float(step),
            "backlash": round(profile.backlash, 4), "unconfirmed": unconfirmed, "sign": sign}
