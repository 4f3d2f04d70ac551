"""Controller compensation files: one writer module per controller, one record per controller.

``CONTROLLERS`` is the registry: the CLI's choices and help, the docs' table
(``docs/controllers.md``) and the workflow (``pipeline.workflows.compensate``) all read it.

Each writer takes an ``AxisProfile`` (``pipeline.compensation.profile``), an output folder and
``Options`` and returns ``{"files": {role: path}, "interpolation_error_um", "points",
"spacing_mm", "backlash", "unconfirmed"}``; the roles (``table``, ``parameters``) are what the
record's reader reads back for the closed-loop check.

The readers belong to the twin's controller model (``models.physics.controller.READERS``):
how a controller applies its file is physics the twin needs without the pipeline, and models
never import the pipeline. So the model holds the readers by name and each record here reads
through the model's reader of its own name; ``tests/test_controllers.py`` checks that both
name the same controllers. Writers and readers are imported on first call: the CLI reads the
records for its help on every start, which must not pay for numpy and pandas.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

from features.readings.errors import InputError


@dataclass(frozen=True)
class Controller:
    """One controller the product writes compensation files for.

    Attributes
    ----------
    name : str
        The name a user gives (``controller="siemens"``, ``--controller siemens``).
    label : str
        The controller as its maker names it.
    aliases : tuple of str
        Other names accepted for it.
    writer : callable
        ``writer(profile, out_dir, options) -> dict``: writes the files of one machine axis.
    reader : callable
        ``reader(files) -> models.physics.controller.Compensation``: reads them back as the
        controller applies them (the closed-loop check).
    kind : str
        ``"table"``: position error and reversal; ``"scalar"``: reversal (backlash) only.
    units : str
        Units of the values in the written files.
    axes : tuple of str
        Axis kinds it compensates: ``"linear"`` (X, Y, Z) and/or ``"rotary"`` (A, B, C).
    files : str
        What is written per machine axis.
    description : str
        One line for help texts and the docs' table.
    """

    name: str
    label: str
    aliases: tuple[str, ...]
    writer: Callable
    reader: Callable
    kind: str
    units: str
    axes: tuple[str, ...]
    files: str
    description: str


def _writer(module: str, function: str = "write") -> Callable:
    """``pipeline.compensation.<module>.<function>``, imported on first call."""
    def write(profile, out_dir, options) -> dict:
        writer = getattr(importlib.import_module(f"pipeline.compensation.{module}"), function)
        return writer(profile, out_dir, options)

    write.__doc__ = f"Write the files of one machine axis (``{module}.{function}``)."
    return write


def _reader(name: str) -> Callable:
    """``models.physics.controller.READERS[name]``, imported on first call."""
    def read(files: dict):
        from models.physics.controller import READERS

        return READERS[name](files)

    read.__doc__ = f"Read back the files of one machine axis as {name} applies them."
    return read


BOTH = ("linear", "rotary")

CONTROLLERS = {c.name: c for c in (
    Controller("linuxcnc", "LinuxCNC", ("emc2",), _writer("linuxcnc"), _reader("linuxcnc"),
               kind="table", units="mm (deg)", axes=BOTH, files="`.comp` table, INI snippet",
               description="COMP_FILE_TYPE 0 table per direction (the reversal included)"),
    Controller("siemens", "Siemens SINUMERIK", ("sinumerik", "840d", "840dsl", "828d"),
               _writer("siemens"),
               _reader("siemens"), kind="table", units="mm (deg)", axes=BOTH,
               files="EEC `.INI`, MD32450 `.INI`",
               description="EEC table of the mean error and MD32450 BACKLASH"),
    Controller("fanuc", "Fanuc", ("0i", "30i", "31i"), _writer("fanuc"), _reader("fanuc"), kind="table",
               units="detection units (`fanuc_unit_um`)", axes=BOTH, files="parameter sheet",
               description="pitch-error increments (3620-3624) and 1851 backlash"),
    Controller("heidenhain", "Heidenhain TNC", ("tnc", "tnc640", "tnc530", "tnc7"),
               _writer("heidenhain"),
               _reader("heidenhain"), kind="table", units="mm (deg)", axes=BOTH,
               files="`.COM` table, MP list",
               description="nonlinear axis-error table and MP710 backlash"),
    Controller("marlin", "Marlin", (), _writer("scalar", "write_marlin"), _reader("marlin"),
               kind="scalar", units="mm", axes=("linear",), files="G-code",
               description="M425 backlash distance"),
    Controller("reprap", "RepRapFirmware", ("rrf", "reprapfirmware"),
               _writer("scalar", "write_reprap"), _reader("reprap"), kind="scalar", units="mm",
               axes=("linear",), files="G-code", description="M425 backlash (RRF 3.5 or later)"),
    Controller("grblhal", "grblHAL", (), _writer("scalar", "write_grblhal"), _reader("grblhal"),
               kind="scalar", units="mm", axes=("linear",), files="settings",
               description="$160-$162 backlash"),
    Controller("csv", "CSV", (), _writer("csvtable"), _reader("csv"), kind="table",
               units="um, mm", axes=BOTH, files="`.csv` table",
               description="everything per target, signs in the column names"),
)}


def names() -> list[str]:
    """The controller names, in the registry's order."""
    return list(CONTROLLERS)


def resolve(controller) -> list[str]:
    """Controller names from ``controller``: a name or alias, a comma-separated text of them,
    a list of them, or ``"all"``; repeated names count once.

    Raises
    ------
    InputError
        For an unknown or empty name (``parameter="controller"``).
    """
    given = controller.split(",") if isinstance(controller, str) else list(controller)
    wanted = [str(n).strip().lower() for n in given if str(n).strip()]
    if wanted == ["all"]:
        return names()
    lookup = {alias: c.name for c in CONTROLLERS.values() for alias in (c.name, *c.aliases)}
    unknown = [n for n in wanted if n not in lookup]
    if unknown or not wanted:
        raise InputError(f"unknown controller {unknown[0] if unknown else controller!r}; "
                         f"expected {', '.join(CONTROLLERS)} or all", parameter="controller")
    return list(dict.fromkeys(lookup[n] for n in wanted))


def help_text() -> str:
    """The names and what each writes, for a help text."""
    return "; ".join(f"{c.name} ({c.description})" for c in CONTROLLERS.values())


def markdown_table() -> str:
    """The docs' table of controllers (``docs/controllers.md`` holds it verbatim)."""
    rows = ["| name | controller | aliases | writes | values in | axes | compensates |",
            "|---|---|---|---|---|---|---|"]
    for c in CONTROLLERS.values():
        compensates = ("position error and reversal" if c.kind == "table" else
                       "reversal (backlash) only")
        aliases = ", ".join(f"`{a}`" for a in c.aliases) or "-"
        rows.append(f"| `{c.name}` | {c.label} | {aliases} | "
                    f"{c.files} | {c.units} | {', '.join(c.axes)} | {compensates}: "
                    f"{c.description} |")
    return "\n".join(rows) + "\n"
