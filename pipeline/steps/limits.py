"""Backlash limits per machine and axis, each in its axis's unit (``--limits LIMITS.toml``).

One table per machine, one key per axis named with the unit of its limit: ``um`` for a linear
axis, ``arcsec`` for a rotary one (A, B, C), so a limit is never read in the wrong unit::

    # LIMITS.toml
    [M01]
    X_um = 8.0
    C_arcsec = 40.0

    [M02]
    Y_um = 6.5

An axis without an entry takes ``--threshold-um`` (linear) or ``--threshold-arcsec``
(rotary). ``fleet`` and ``drift`` read it (``models.condition.drift.limit_of``).
"""

from __future__ import annotations

import math
import os

from features.readings.errors import InputError
from features.readings.schema import deviation_unit

UNITS = ("um", "arcsec")


def read_limits(source, parameter: str = "limits") -> dict[tuple[str, str], float]:
    """The limits of a TOML file or of a dict of the same shape, by (machine, axis).

    Raises
    ------
    InputError
        One line naming the file and the key: a key that is not a machine's table or not
        ``<axis>_um`` / ``<axis>_arcsec``, a unit that is not the axis's, a limit that is not
        a positive finite number.
    """
    from features.readings.fileio import read_toml

    if isinstance(source, (str, os.PathLike)):
        file = str(source)
        try:
            table = read_toml(source, "limits file")
        except InputError as err:  # unreadable or not TOML: name the option too
            raise InputError(err.message, file=file, parameter=parameter) from None
    else:
        table, file = source, None
    limits = {}
    for machine, axes in table.items():
        if not isinstance(axes, dict):
            raise InputError(f"key {machine!r}: expected a table [{machine}] of limits per "
                             "axis, e.g. X_um = 8.0", file=file, parameter=parameter)
        for key, value in axes.items():
            limits[(str(machine), _axis(machine, key, file, parameter))] = _limit(
                machine, key, value, file, parameter)
    return limits


def _axis(machine: str, key: str, file, parameter: str) -> str:
    """The axis of a key ``<axis>_<unit>``, its unit checked against the axis's."""
    axis, _, unit = str(key).rpartition("_")
    if not axis or unit not in UNITS:
        raise InputError(f"unknown key {machine}.{key}: expected <axis>_um (linear axis) or "
                         "<axis>_arcsec (rotary axis)", file=file, parameter=parameter)
    if unit != deviation_unit(axis):
        raise InputError(f"{machine}.{key}: axis {axis} is measured in {deviation_unit(axis)}, "
                         f"not {unit}; write {axis}_{deviation_unit(axis)}", file=file,
                         parameter=parameter)
    return axis


def _limit(machine: str, key: str, value, file, parameter: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0):
        raise InputError(f"{machine}.{key} = {value!r}: expected a positive finite number",
                         file=file, parameter=parameter)
    return float(value)


def limit_notes(limits: dict | None, threshold_um, threshold_arcsec, data, readings,
                source=None, also=frozenset()) -> list[str]:
    """Notes on limits that can apply to nothing: a limit of a machine or axis the data do
    not hold (a store: anywhere in it, so a selection of other machines says nothing), and a
    threshold whose unit no axis of the readings has (``threshold_um`` on rotary axes only,
    which are in arcsec). A slip here would otherwise pass as "no alert". ``source`` is the
    limits file (or the dict) as given, named in the notes. ``also``: (machine, axis) pairs a
    limit applies to beyond the readings (a rotary axis's probing records in a store)."""
    from features.readings.schema import ROTARY_AXES

    held = _held_axes(data, readings) | set(also)
    notes = []
    machines = {m for m, _ in held}
    name = str(source) if isinstance(source, (str, os.PathLike)) else "limits"
    for machine, axis in sorted(limits or {}):
        key = f"{machine}.{axis}_{deviation_unit(axis)}"
        if machine not in machines:
            notes.append(f"{name}: {key}: the data hold no machine {machine} (machines "
                         f"{_listed(sorted(machines))}); the limit applies to nothing")
        elif (machine, axis) not in held:
            axes = sorted(a for m, a in held if m == machine)
            notes.append(f"{name}: {key}: machine {machine} has no axis {axis} in the data "
                         f"(axes {', '.join(axes)}); the limit applies to nothing")
    axes = set(readings["axis"].unique()) | {a for _, a in also}
    rotary = axes <= set(ROTARY_AXES)
    if threshold_um is not None and rotary:
        notes.append(f"threshold_um (--threshold-um {threshold_um:g}) is a limit in um of the "
                     f"linear axes; the data hold rotary axes only ({', '.join(sorted(axes))}), "
                     "in arcsec: give threshold_arcsec (--threshold-arcsec)")
    if threshold_arcsec is not None and not axes & set(ROTARY_AXES):
        notes.append(f"threshold_arcsec (--threshold-arcsec {threshold_arcsec:g}) is a limit "
                     "in arcsec of the rotary axes; the data hold linear axes only "
                     f"({', '.join(sorted(axes))}), in um: give threshold_um (--threshold-um)")
    return notes


def _held_axes(data, readings) -> set[tuple[str, str]]:
    """(machine, axis) pairs the data hold: a whole store's, else the readings'."""
    from pipeline.store import is_store, open_store

    if isinstance(data, (str, os.PathLike)) and is_store(data):
        return set(open_store(data).axes())
    return set(map(tuple, readings[["machine_id", "axis"]].drop_duplicates().to_numpy()))


def _listed(names: list[str], most: int = 5) -> str:
    return ", ".join(names[:most]) + (" ..." if len(names) > most else "")
