"""Controller compensation files: one writer module per controller, one registry.

Each writer takes an ``AxisProfile`` (``pipeline.compensation.profile``), an output folder and
``Options`` and returns ``{"files": {role: path}, "interpolation_error_um", "points",
"spacing_mm", "backlash", "unconfirmed"}``; the roles (``table``, ``parameters``) are what
``models.physics.controller.load`` reads back for the closed-loop check.
"""

from __future__ import annotations

from pipeline.compensation import csvtable, fanuc, heidenhain, linuxcnc, scalar, siemens

# name: (writer, kind) — kind "table" compensates position and reversal, "scalar" reversal only
CONTROLLERS = {
    "linuxcnc": (linuxcnc.write, "table"),
    "siemens": (siemens.write, "table"),
    "fanuc": (fanuc.write, "table"),
    "heidenhain": (heidenhain.write, "table"),
    "marlin": (scalar.write_marlin, "scalar"),
    "reprap": (scalar.write_reprap, "scalar"),
    "grblhal": (scalar.write_grblhal, "scalar"),
    "csv": (csvtable.write, "table"),
}


def names() -> list[str]:
    return list(CONTROLLERS)
