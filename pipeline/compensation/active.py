"""Recalibration: the tests were measured with a compensation file active on the machine.

The controller adds the active file's offset o(x, d) [mm] to the command at position x when
moving in direction d (``models.physics.controller.Compensation``), so a test run with it
measures the axis's own deviation plus that offset:

    x_measured(x, d) = x_axis(x, d) + s o(x, d)            [um; s = um per mm, arcsec per deg]

The axis without any compensation is therefore ``x_axis = x_measured - s o``, with o
interpolated at the new targets as the controller interpolates it. A file written for
``x_axis`` is the active file plus the measured residual, in the controller's own format and
sign convention, so every writer serves recalibration unchanged (data contract section 6).

The files given are recognised by their content (``Controller.recognise``) and refused when
they are of another controller, name another axis (``Controller.axis_patterns``), state
another unit, or cover another stretch of travel than the tests (a table in inches, or of
another axis).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from features.readings import schema
from features.readings.errors import InputError, note
from pipeline.compensation import CONTROLLERS, read
from pipeline.compensation.common import AXIS_INDEX, in_units

AXES = {i: a for a, i in AXIS_INDEX.items()}
MIN_COVER = 0.5  # share of the tests' travel an active table must cover
RECALIBRATED = "recalibration: new file = active file + measured residual"


def read_active(paths, controller: str, profile, options):
    """The active compensation of one machine axis, read from its files as ``controller``
    applies them.

    Parameters
    ----------
    paths : path or list of paths
        The active files (a table and/or a parameter file of one controller).
    controller : str
        Name of the controller written for; the files must be its own.
    profile : AxisProfile
        The measured axis (its axis name and targets [mm] are checked against the files).
    options : Options
        ``fanuc_unit_um`` and ``sign`` (how the table's values are read).

    Returns
    -------
    models.physics.controller.Compensation

    Raises
    ------
    InputError
        An unreadable file, a file of another controller, axis or unit, or a table that does
        not cover the tests' travel (``parameter="active"``).
    """
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise InputError("expected at least one compensation file", parameter="active")
    texts = {path: _text(path) for path in paths}
    files = _roles(texts, controller)
    _check_axis(texts, controller, profile.axis)
    _check_unit(texts, controller, profile.axis, options)
    record = CONTROLLERS[controller]
    for role in dict(record.recognise):
        if role not in files:
            note(f"no active {record.label} {role} file given: what it holds is taken as not "
                 "active")
    try:
        comp = read(controller, files, options.sign)
    except InputError as err:
        raise _active(err) from None
    _check_cover(comp, profile, files.get("table", paths[0]))
    return comp


def without(profile, comp):
    """The axis as it is without the active compensation ``comp``: the measured means minus
    the offsets the controller added at each target and direction [um]."""
    up = profile.scale * comp.offset_mm(profile.target, 1)
    down = profile.scale * comp.offset_mm(profile.target, -1)
    return replace(profile, mean_up=profile.mean_up - up, mean_down=profile.mean_down - down,
                   notes=[*profile.notes, RECALIBRATED])


def changes(profile, active, new) -> pd.DataFrame:
    """Per target, the correction the controller adds moving + and - with the active and with
    the new file, and the change [um] (a constant shift of a table that is 0 at its reference
    point changes no ISO figure)."""
    x = profile.target
    out = {"target_mm": x}
    for side, d in (("plus", 1), ("minus", -1)):
        before = profile.scale * active.offset_mm(x, d)
        after = profile.scale * new.offset_mm(x, d)
        out |= {f"active_{side}_um": before, f"new_{side}_um": after,
                f"change_{side}_um": after - before}
    return pd.DataFrame({in_units(name, profile): values for name, values in out.items()})


def _text(path: Path) -> str:
    from models.physics.controller import file_text

    try:
        return file_text(path)
    except InputError as err:
        raise _active(err) from None


def _active(err: InputError) -> InputError:
    """``err`` naming ``--active`` when it names no option."""
    return InputError(err.message, file=err.file, row=err.row, column=err.column,
                      parameter=err.parameter or "active")


def _roles(texts: dict, controller: str) -> dict:
    """Role -> path of the given files; each must be ``controller``'s file of one role."""
    files = {}
    for path, text in texts.items():
        found = {name: role for name, record in CONTROLLERS.items()
                 for role, pattern in reversed(record.recognise)
                 if re.search(pattern, text, re.MULTILINE)}
        if not found:
            raise InputError("not a compensation file of a supported controller "
                             f"({', '.join(CONTROLLERS)})", file=path, parameter="active")
        if controller not in found:
            labels = "/".join(CONTROLLERS[n].label for n in found)
            raise InputError(f"a {labels} file; the new file is for "
                             f"{CONTROLLERS[controller].label}: give --controller "
                             f"{next(iter(found))}", file=path, parameter="active")
        role = found[controller]
        if role in files:
            raise InputError(f"a second {role} file (first: {files[role]})", file=path,
                             parameter="active")
        files[role] = path
    return files


def _check_axis(texts: dict, controller: str, axis: str) -> None:
    """Refuse a file naming another axis; note when no file names one."""
    named = False
    for path, text in texts.items():
        for pattern in CONTROLLERS[controller].axis_patterns:
            for m in re.finditer(pattern, text, re.MULTILINE):
                found = _axis(m)
                named = True
                if found != axis:
                    raise InputError(f"a compensation of axis {found}; the tests are of axis "
                                     f"{axis}", file=path, parameter="active")
    if not named:
        note(f"the active files do not name their axis: taken as axis {axis}")


def _axis(m: re.Match) -> str:
    groups = m.groupdict()
    if groups.get("axis"):
        return groups["axis"]
    index = int(groups["joint"]) if groups.get("joint") else int(groups["ax"]) - 1
    return AXES.get(index, f"number {index}")


def _check_unit(texts: dict, controller: str, axis: str, options) -> None:
    """Units a file states: Fanuc's detection unit must be the one written (``fanuc_unit_um``
    thousandths of the position unit: um, or 0.001 deg on a rotary axis), a Heidenhain table
    must be in the axis's position unit (MM, DEG on a rotary axis)."""
    rotary = schema.is_rotary(axis)
    detection = (options.fanuc_unit_um / 1000.0, "deg") if rotary else (options.fanuc_unit_um,
                                                                         "um")
    position = "DEG" if rotary else "MM"
    checks = {"fanuc": (r"^\s*DETECTION UNIT\s*=\s*(\S+\s*\w+)",
                        lambda unit: _same_unit(unit, *detection),
                        (f"detection unit {{}}; the new sheet is written in {detection[0]:g} "
                         f"{detection[1]} (--fanuc-unit-um)")),
              "heidenhain": (r"^\s*BEGIN\s+\S+\.COM\s+(\w+)",
                             lambda unit: unit.upper() == position,
                             f"a table in {{}}; expected {position} for axis {axis}")}
    if controller not in checks:
        return
    pattern, same, message = checks[controller]
    for path, text in texts.items():
        if (m := re.search(pattern, text, re.MULTILINE)) and not same(m[1]):
            raise InputError(message.format(m[1]), file=path, parameter="active")


def _same_unit(text: str, value: float, unit: str) -> bool:
    """Whether ``text`` (``"1 um"``, ``"0.001 deg"``) states ``value`` in ``unit``."""
    number, _, stated = text.partition(" ")
    try:
        return stated.strip() == unit and bool(np.isclose(float(number), value))
    except ValueError:
        return False


def _check_cover(comp, profile, path) -> None:
    """An active table must cover most of the tests' travel [mm]; one that does not is of
    another axis or in other units (inches)."""
    if not len(comp.nominal_mm):
        return
    low, high = float(profile.target.min()), float(profile.target.max())
    overlap = min(high, comp.nominal_mm[-1]) - max(low, comp.nominal_mm[0])
    if overlap < MIN_COVER * (high - low):
        raise InputError(f"the table covers {comp.nominal_mm[0]:g} to {comp.nominal_mm[-1]:g}, "
                         f"the tests {low:g} to {high:g} mm: another axis, or other units?",
                         file=path, parameter="active")
