"""Controller compensation files: one writer module per controller, one record per controller.

``CONTROLLERS`` is the registry: the CLI's choices and help, the docs' table
(``docs/controllers.md``) and the workflow (``pipeline.workflows.compensate``) all read it.

Each writer takes an ``AxisProfile`` (``pipeline.compensation.profile``), a folder made in
memory (``features.readings.fileio.MemoryFolder``) and ``Options`` and returns ``{"files": {role: path}, "interpolation_error_um", "points",
"spacing_mm", "backlash", "unconfirmed"}``; the roles (``table``, ``parameters``) are what the
record's reader reads back for the closed-loop check.

The readers belong to the twin's controller model (``models.physics.controller.READERS``):
how a controller applies its file is physics the twin needs without the pipeline, and models
never import the pipeline. So the model holds the readers by name and each record here reads
through the model's reader of its own name; ``tests/test_controllers.py`` checks that both
name the same controllers. Writers and readers are imported on first call: the CLI reads the
records for its help on every start, which must not pay for numpy and pandas.

``read(name, files, sign)`` reads files back with a site's table sign convention; each record's
``recognise`` and ``axis_patterns`` tell a file's controller, role and axis from its text, for
recalibration with an active file (``pipeline.compensation.active``).
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
        ``writer(profile, out_dir, options) -> dict``: makes the files of one machine axis in
        ``out_dir``, a ``features.readings.fileio.MemoryFolder`` (written to disk once, by
        the result).
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
    sign : str or None
        What a positive table value means in the controller's documented convention:
        ``"error"`` (measured - nominal) or ``"correction"`` (added to the command); None
        when the format fixes it (positions, named columns) or there is no table.
    per_direction : bool
        Whether the files carry one table per approach direction, so that a reversal value
        varying along the axis is compensated (Fanuc: written so when it varies,
        ``common.direction_dependent``).
    recognise : tuple of (str, str)
        ``(role, regular expression)``: a file whose text the expression finds (multi-line
        mode) is this controller's file of that role (``--active``).
    axis_patterns : tuple of str
        Expressions naming the axis a file is for: group ``axis`` a letter, ``joint`` the
        0-based index (X=0 ... C=5) or ``ax`` the 1-based ``AXn``.
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
    sign: str | None = None
    per_direction: bool = False
    recognise: tuple[tuple[str, str], ...] = ()
    axis_patterns: tuple[str, ...] = ()


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
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_M425 = ((("parameters", r"^\s*M425\s+[XYZ]"),), (r"^\s*M425\s+(?P<axis>[XYZ])",))

CONTROLLERS = {c.name: c for c in (
    Controller("linuxcnc", "LinuxCNC", ("emc2", "lcnc"), _writer("linuxcnc"), _reader("linuxcnc"),
               kind="table", units="mm (deg)", axes=BOTH, files="`.comp` table, INI snippet",
               description="COMP_FILE_TYPE 0 table per direction (the reversal included)",
               per_direction=True,
               recognise=(("table", rf"\A[ \t]*{_NUMBER}[ \t]+{_NUMBER}[ \t]+{_NUMBER}[ \t]*$"),
                          ("parameters", r"^\s*(COMP_FILE_TYPE\s*=|\[JOINT_\d+\])")),
               axis_patterns=(r"^\s*\[JOINT_(?P<joint>\d)\]",)),
    Controller("siemens", "Siemens SINUMERIK", ("sinumerik", "840d", "840dsl", "840d-sl", "828d"),
               _writer("siemens"),
               _reader("siemens"), kind="table", units="mm (deg)", axes=BOTH,
               files="EEC `.INI`, MD32450 `.INI`",
               description=("EEC table of the mean error (modulo over a full turn) and "
                            "MD32450 BACKLASH"), sign="error",
               recognise=(("table", r"^\s*\$AA_ENC_COMP\["),
                          ("parameters", r"^\s*\$MA_BACKLASH\[")),
               axis_patterns=(r"^\s*\$(?:AA_ENC_COMP\w*|MA_BACKLASH)\[\d+,(?:\d+,)?AX(?P<ax>\d+)\]",)),
    Controller("fanuc", "Fanuc", ("0i", "0i-d", "0i-f", "30i", "30i-b", "31i", "31i-b"),
               _writer("fanuc"), _reader("fanuc"), kind="table",
               units="detection units (`fanuc_unit_um`: um, 0.001 deg)", axes=BOTH,
               files="parameter sheet",
               description=("pitch-error increments (3620-3625, rotary-axis type over a full "
                            "turn) and 1851 backlash; when the reversal varies along the axis, "
                            "one table per direction (3605#0, 3626, 3627) instead of 1851"),
               sign="correction", per_direction=True,
               recognise=(("parameters", r"^\s*(PITCH\s+\d+|1851\s+\w+)\s*="),),
               axis_patterns=(r"^\s*\d{4}(?:#\d)?\s+(?P<axis>[XYZABC])\s*=",)),
    Controller("heidenhain", "Heidenhain TNC", ("tnc", "tnc640", "tnc530", "tnc7"),
               _writer("heidenhain"),
               _reader("heidenhain"), kind="table", units="mm (deg)", axes=BOTH,
               files="`.COM` table, MP list",
               description="nonlinear axis-error table and MP710 backlash", sign="error",
               recognise=(("table", r"^\s*BEGIN\s+\S+\.COM\b"),
                          ("parameters", r"^\s*MP7[15]0\.\d+\s*=")),
               axis_patterns=(r"^\s*NR\s+(?P<axis>[XYZABC])-POS",
                              r"^\s*MP7[15]0\.(?P<joint>\d)\s*=")),
    Controller("marlin", "Marlin", (), _writer("scalar", "write_marlin"), _reader("marlin"),
               kind="scalar", units="mm", axes=("linear",), files="G-code",
               description="M425 backlash distance", recognise=_M425[0],
               axis_patterns=_M425[1]),
    Controller("reprap", "RepRapFirmware", ("rrf", "reprapfirmware"),
               _writer("scalar", "write_reprap"), _reader("reprap"), kind="scalar", units="mm",
               axes=("linear",), files="G-code", description="M425 backlash (RRF 3.5 or later)",
               recognise=_M425[0], axis_patterns=_M425[1]),
    Controller("grblhal", "grblHAL", (), _writer("scalar", "write_grblhal"), _reader("grblhal"),
               kind="scalar", units="mm", axes=("linear",), files="settings",
               description="$160-$162 backlash",
               recognise=(("parameters", r"^\s*\$16[0-2]\s*="),),
               axis_patterns=(r"^\s*\$16(?P<joint>[0-2])\s*=",)),
    Controller("csv", "CSV", (), _writer("csvtable"), _reader("csv"), kind="table",
               units="um, mm", axes=BOTH, files="`.csv` table",
               description="everything per target, signs in the column names",
               per_direction=True,
               recognise=(("table", (r"^[^#\n]*\btarget_(?:mm|deg)\b[^\n]*"
                                     r"\bcorrection_plus_(?:um|arcsec)\b")),),
               axis_patterns=(r"^[^,#\n]*,(?P<axis>[XYZABC]),(?:measured|predicted),",)),
)}
SIGNS = ("error", "correction")


def read(name: str, files: dict, sign: str | None = None):
    """The files of one machine axis read back as controller ``name`` applies them
    (``models.physics.controller.Compensation``), the table's values taken with ``sign``
    (``"error"`` or ``"correction"``; default the controller's documented convention)."""
    record = CONTROLLERS[name]
    comp = record.reader(files)
    if sign is not None and record.sign is not None and sign != record.sign:
        from models.physics.controller import table_flipped

        comp = table_flipped(comp)
    return comp


def names() -> list[str]:
    """The controller names, in the registry's order."""
    return list(CONTROLLERS)


def register(record: Controller) -> Controller:
    """Add a controller from outside this package: its record here and its reader in the
    twin's controller model (``models.physics.controller.READERS``), so that ``compensate``,
    ``--controller``, the closed-loop check and the docs' table read it from then on.

    Raises
    ------
    ValueError
        When the name or an alias is taken already.
    """
    from models.physics.controller import READERS

    taken = {alias for c in CONTROLLERS.values() for alias in (c.name, *c.aliases)} | {"all"}
    clash = sorted(taken & {record.name, *record.aliases})
    if clash:
        raise ValueError(f"controller name {clash[0]!r} is taken already")
    CONTROLLERS[record.name] = record
    READERS[record.name] = record.reader
    return record


def unregister(name: str) -> None:
    """Remove controller ``name`` (one added by ``register``) and its reader."""
    from models.physics.controller import READERS

    del CONTROLLERS[name], READERS[name]


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


def controllers_table() -> str:
    """The docs' table of controllers (``docs/controllers.md``, filled in by ``docs/hooks.py``
    as the site is built)."""
    rows = [("| name | controller | aliases | writes | values in | table sign (`--sign`) | "
            "axes | compensates |"),
            "|---|---|---|---|---|---|---|---|"]
    for c in CONTROLLERS.values():
        compensates = ("position error and reversal" if c.kind == "table" else
                       "reversal (backlash) only")
        reversal = ("per direction" if c.per_direction else
                    "one table + scalar reversal" if c.kind == "table" else "scalar")
        aliases = ", ".join(f"`{a}`" for a in c.aliases) or "-"
        sign = c.sign or ("fixed by the format" if c.kind == "table" else "-")
        rows.append(f"| `{c.name}` | {c.label} | {aliases} | "
                    f"{c.files} | {c.units} | {sign} | {', '.join(c.axes)} | {compensates} "
                    f"({reversal}): {c.description} |")
    return "\n".join(rows) + "\n"
