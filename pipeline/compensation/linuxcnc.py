"""LinuxCNC: ``COMP_FILE_TYPE 0`` joint compensation table and an INI snippet.

Table (``*.comp``): one line per point, ``nominal actual_plus actual_minus`` in machine units
(mm, deg), nominals strictly ascending, at most 256 lines, nothing else: LinuxCNC stops reading
at the first line that is not three numbers (``usrmotLoadComp``). "actual" is where the axis
really is when commanded to ``nominal`` approaching in that direction, i.e. nominal + deviation;
LinuxCNC adds ``nominal - actual`` of the current direction to the commanded position, linearly
interpolated between nominals. ``BACKLASH`` is not used when ``COMP_FILE`` is set, so the table
carries the reversal; the INI gives ``BACKLASH`` (commented out) for a scalar-only set-up.
LinuxCNC interpolates between any ascending nominals, so the measured targets are used as they
are (no resampling, interpolation error 0 at the targets). Outside the table LinuxCNC holds the
first and last trims (``command.c``, ``EMCMOT_SET_JOINT_COMP``: the entries at -DBL_MAX and
+DBL_MAX take the end trims with zero slope). Sources: LinuxCNC INI documentation
(``[JOINT_<num>]``: TYPE, COMP_FILE, COMP_FILE_TYPE, BACKLASH), ``usrmotintf.cc``,
``control.c``, ``command.c``.

Rotary joints (A, B, C): ``TYPE = ANGULAR`` in the snippet; nominal, actual and BACKLASH in
degrees (the deviations measured in arcsec divided by 3600). The table is not wrapped: the trims
apply to the joint position as it is. A rotary axis measured over a whole turn
(``common.full_turn``) gets one more line closing the turn, at first target + 360 deg with the
first target's deviations, so that positions between the last target and the full turn
interpolate towards the first; whether a wrapped rotary axis (``[AXIS_<letter>]
WRAPPED_ROTARY = 1``) keeps its joint position within that turn is not confirmed.
"""

from __future__ import annotations

from features.readings.errors import InputError
from features.readings.fileio import write_text
from pipeline.compensation.common import AXIS_INDEX, closed_turn, header, units

MAX_LINES = 256


def write(profile, out_dir, options) -> dict:
    x, up, down = closed_turn(profile)
    if len(x) > MAX_LINES:
        raise InputError(f"{len(x)} table lines; a LinuxCNC table holds at most {MAX_LINES}",
                         parameter="data")
    plus = x + up / profile.scale
    minus = x + down / profile.scale
    table = "".join(f"{a:.7f} {b:.7f} {c:.7f}\n" for a, b, c in zip(x, plus, minus))
    comp = out_dir / f"{profile.stem}.comp"
    joint = AXIS_INDEX[profile.axis]
    ini = header(profile, "LinuxCNC", ";", [
        f"add to [JOINT_{joint}] (joint number assumes trivkins X=0 Y=1 Z=2 A=3 B=4 C=5)",
        ("COMP_FILE columns: nominal, actual position moving +, actual position moving - "
        "(actual = nominal + measured deviation)"),
        "BACKLASH is ignored when COMP_FILE is set: the table carries the reversal",
        *_rotary_notes(profile),
    ]) + (f"[JOINT_{joint}]\n{_joint_type(profile)}COMP_FILE = {comp.name}\nCOMP_FILE_TYPE = 0\n"
          f"; scalar-only alternative (without COMP_FILE):\n"
          f"; BACKLASH = {profile.backlash / profile.scale:.6f}\n")
    write_text(comp, table)
    snippet = write_text(out_dir / f"{profile.stem}_linuxcnc.ini", ini)
    return {"files": {"table": comp, "parameters": snippet}, "interpolation_error_um": 0.0,
            "points": len(x), "spacing_mm": None,
            "backlash": round(profile.backlash, 4), "unconfirmed": []}


def _joint_type(profile) -> str:
    """``TYPE = ANGULAR`` line of a rotary joint (a linear joint's default type is left out)."""
    return "TYPE = ANGULAR\n" if units(profile)[0] == "deg" else ""


def _rotary_notes(profile) -> list[str]:
    """What a rotary joint needs: the table and BACKLASH in degrees (an angular joint's machine
    units); the table ascends within one turn at most and is not wrapped."""
    pos, dev = units(profile)
    if pos != "deg":
        return []
    x = closed_turn(profile)[0]
    cover = f"the table covers {x[0]:g} to {x[-1]:g} deg" + (
        f", its last line closing the turn with the deviations at {x[0]:g} deg"
        if len(x) > len(profile.target) else "")
    return [(f"rotary joint {profile.axis}: TYPE = ANGULAR; nominal, actual and BACKLASH in "
             f"degrees (deviations measured in {dev}, divided by 3600)"),
            f"{cover}; LinuxCNC does not wrap it: outside it the end trims are held"]
