"""Controller model: reads a written compensation file and applies it the way that controller does.

Every supported controller reduces to one structure (``Compensation``): per approach direction
an offset table over the axis position that the controller adds to the *commanded* position
(linear interpolation between points, the end values held outside the table), plus a scalar
backlash b added at every reversal (+b/2 moving +, -b/2 moving -; a controller that adds the
whole b after a reversal to one side differs by the constant b/2, which no ISO 230-2 figure
sees). The parsers below turn each file's own sign convention into those offsets:

- LinuxCNC ``COMP_FILE_TYPE 0`` (``nominal actual_plus actual_minus`` [mm]): the motion module
  adds ``nominal - actual`` of the current direction to the commanded position
  (``usrmotLoadComp`` converts type-0 triplets to ``nom - fwd``, ``nom - rev``; ``control.c``
  adds the interpolated trim to ``joint_pos_cmd``); reading stops at the first line that is not
  three numbers; at most 256 lines; ``BACKLASH`` is ignored when ``COMP_FILE`` is set.
- SINUMERIK EEC (``$AA_ENC_COMP[0,N,AXn]`` = error [mm], equidistant from ``_MIN`` by
  ``_STEP`` to ``_MAX``): offset = -error, one table for both directions; ``MD32450 BACKLASH``
  [mm] at reversal. With ``$AA_ENC_COMP_IS_MODULO=1`` the table repeats cyclically, the value
  at ``_MAX`` followed at once by the value at ``_MIN`` (function manual K3, 4.4.2.2): the
  position is taken modulo ``_MAX - _MIN`` from ``_MIN``.
- Fanuc (1851 backlash and incremental pitch-error values per section, detection units):
  offset = cumulative sum of the increments from the reference point, linear within a section;
  a rotary axis's table (``3625`` movement per rotation) repeats every rotation; with
  ``3605#0 = 1`` a second table (from point ``3626``, its value at the reference ``3627``)
  applies moving -.
- Heidenhain (``.COM`` error table, ``MP710`` backlash [mm]): offset = -error.
- Marlin / RepRapFirmware ``M425``, grblHAL ``$160-$162``: backlash only [mm].
- CSV written by the product: the ``correction_*`` columns are the offsets.

The twin (``models.physics.axis``) runs the commanded path plus these offsets through its play
operator, so the reversal step is taken up by the clearance exactly as on the machine.

``READERS`` is the controller model's half of the controller records: per controller name, how
the files written for one machine axis are read back. The other half (writer, aliases, units,
axis kinds, description) is ``pipeline.compensation.CONTROLLERS``, keyed by the same names and
holding these readers. The records cannot live here, since their writers are pipeline code and
models never import the pipeline; a test checks that both halves name the same controllers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from features.readings.errors import InputError
from features.readings.validation import finite_number

LINUXCNC_MAX_LINES = 256


@dataclass(frozen=True)
class Compensation:
    """What a controller adds to the commanded position [mm] (deg for a rotary axis).

    ``nominal_mm`` ascending table positions (may be empty), ``plus_mm`` / ``minus_mm`` the
    offsets at those positions when moving + / -, ``backlash_mm`` the scalar reversal value,
    ``period_mm`` the range after which a modulo table repeats (None: the end values are held
    outside the table).
    """

    nominal_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    plus_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    minus_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    backlash_mm: float = 0.0
    source: str = ""
    period_mm: float | None = None

    def table_position_mm(self, position_mm) -> np.ndarray:
        """Where in the table the controller looks up ``position_mm``: the position itself, or
        for a modulo table ``nominal_0 + (position - nominal_0) mod period``."""
        x = np.asarray(position_mm, float)
        if self.period_mm is None or not len(self.nominal_mm):
            return x
        return self.nominal_mm[0] + np.mod(x - self.nominal_mm[0], self.period_mm)

    def offset_mm(self, position_mm, direction) -> np.ndarray:
        """Offset [mm] added to the commanded ``position_mm`` moving in ``direction`` (+1/-1)."""
        x = self.table_position_mm(position_mm)
        d = np.broadcast_to(np.asarray(direction, float), x.shape)
        out = np.where(d > 0, self.backlash_mm / 2, -self.backlash_mm / 2)
        if len(self.nominal_mm):
            plus = np.interp(x, self.nominal_mm, self.plus_mm)
            minus = np.interp(x, self.nominal_mm, self.minus_mm)
            out = out + np.where(d > 0, plus, minus)
        return out

    def motor_path(self, commanded_mm, direction) -> np.ndarray:
        """Commanded path with the compensation, two points per move [mm]: where the move
        starts (the previous waypoint, already with the new direction's offset: the reversal
        step comes first) and where it ends. Shape (2 * waypoints,)."""
        cmd = np.asarray(commanded_mm, float)
        d = np.asarray(direction, float)
        prev = np.r_[cmd[0], cmd[:-1]]
        start = prev + self.offset_mm(prev, d)
        end = cmd + self.offset_mm(cmd, d)
        return np.stack([start, end], axis=1).ravel()


def flipped(comp: Compensation) -> Compensation:
    """The same compensation with every sign reversed (what a sign mistake does)."""
    return replace(table_flipped(comp), backlash_mm=-comp.backlash_mm,
                   source=comp.source + " (flipped)")


def table_flipped(comp: Compensation) -> Compensation:
    """The same compensation with the table's sign reversed and the backlash kept: a table
    file read with the other sign convention (``error`` <-> ``correction``)."""
    return replace(comp, plus_mm=-comp.plus_mm, minus_mm=-comp.minus_mm,
                   source=comp.source + " (table sign reversed)")


# --------------------------------------------------------------------------- parsers


def file_text(path) -> str:
    """The text of a compensation file (UTF-8, else Latin-1, as controls write it): a path,
    or a file made in memory (anything with ``read_bytes``)."""
    path = path if hasattr(path, "read_bytes") else Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise InputError(f"cannot read compensation file: {err.strerror}", file=path) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _ascending(nominal: np.ndarray, path) -> None:
    if len(nominal) and np.any(np.diff(nominal) <= 0):
        row = int(np.argmax(np.diff(nominal) <= 0)) + 2
        raise InputError("nominal positions must be strictly ascending", file=path, row=row)


LINUXCNC_COLUMNS = ("nominal", "actual position moving +", "actual position moving -")


def linuxcnc(comp_path, ini_path=None) -> Compensation:
    """LinuxCNC joint compensation: a ``COMP_FILE_TYPE 0`` table and/or ``BACKLASH`` (INI)."""
    backlash, comp_file, comp_type = 0.0, None, 0
    if ini_path is not None:
        for row, line in enumerate(file_text(ini_path).splitlines(), start=1):
            line = line.split("#")[0].strip()
            if line.startswith(";") or "=" not in line:
                continue
            key, value = (p.strip() for p in line.split("=", 1))
            if key == "BACKLASH":
                backlash = finite_number(value, ini_path, row, "BACKLASH")
            elif key == "COMP_FILE":
                comp_file = value
            elif key == "COMP_FILE_TYPE":
                comp_type = int(finite_number(value, ini_path, row, "COMP_FILE_TYPE"))
        if comp_type != 0:
            raise InputError(f"COMP_FILE_TYPE {comp_type}: only type 0 is modelled",
                             file=ini_path)
    if comp_path is None and comp_file is not None:
        raise InputError(f"COMP_FILE {comp_file} is set but not given", file=ini_path)
    if comp_path is None or (ini_path is not None and comp_file is None):
        return Compensation(backlash_mm=backlash, source="linuxcnc BACKLASH")
    rows = []
    for row, line in enumerate(file_text(comp_path).splitlines(), start=1):
        parts = line.split()
        if len(parts) < 3:  # LinuxCNC: sscanf("%lf %lf %lf") != 3 ends the table
            break
        try:
            values = [float(p) for p in parts[:3]]
        except ValueError:
            break
        # sscanf reads "nan" and "inf" too: a table holding them cannot be interpreted
        for name, text, value in zip(LINUXCNC_COLUMNS, parts, values):
            if not np.isfinite(value):
                raise InputError(f"{name}: {text!r} is not a finite number", file=comp_path,
                                 row=row)
        rows.append(values)
    if not rows:
        raise InputError("no 'nominal actual_plus actual_minus' lines", file=comp_path, row=1)
    if len(rows) > LINUXCNC_MAX_LINES:
        raise InputError(f"{len(rows)} lines; LinuxCNC reads at most {LINUXCNC_MAX_LINES}",
                         file=comp_path)
    table = np.asarray(rows)
    _ascending(table[:, 0], comp_path)
    # BACKLASH is not used when COMP_FILE is given: the table carries the reversal
    return Compensation(table[:, 0], table[:, 0] - table[:, 1], table[:, 0] - table[:, 2], 0.0,
                        "linuxcnc COMP_FILE_TYPE 0")


_EEC = re.compile(
    r"\$AA_ENC_COMP(_STEP|_MIN|_MAX|_IS_MODULO)?\[(\d+),(?:(\d+),)?(\w+)\]\s*=\s*(\S+)")


def siemens(eec_path, md_path=None) -> Compensation:
    """SINUMERIK EEC table (``%_N_AX_EEC_INI``) and/or ``MD32450 BACKLASH``.

    A table with ``$AA_ENC_COMP_IS_MODULO[0,AXn]=1`` repeats cyclically: the value at ``_MAX``
    is followed at once by the value at ``_MIN`` (function manual K3, 6FC5397-1BP40-3BA1, 03/2013,
    4.4.2.2), so positions are looked up modulo ``_MAX - _MIN`` from ``_MIN`` (the table's range
    taken as the axis's modulo range) and a value at ``_MAX`` that differs from the one at
    ``_MIN`` is a jump, as on the control.
    """
    backlash = 0.0 if md_path is None else _last_setting(
        md_path, r"\$MA_BACKLASH\[\d+,\w+\]\s*=\s*(\S+)", "MD32450 BACKLASH")
    if eec_path is None:
        return Compensation(backlash_mm=backlash, source="siemens MD32450")
    values, meta = {}, {}
    for row, line in enumerate(file_text(eec_path).splitlines(), start=1):
        line = line.split(";")[0].strip()
        if m := _EEC.fullmatch(line):
            kind, _, index, _, value = m.groups()
            number = finite_number(value, eec_path, row, f"$AA_ENC_COMP{kind or ''}")
            if kind:
                meta[kind] = number
            else:
                values[int(index)] = number
    for kind in ("_STEP", "_MIN", "_MAX"):
        if kind not in meta:
            raise InputError(f"missing $AA_ENC_COMP{kind}", file=eec_path)
    if meta.get("_IS_MODULO", 0) and not meta["_MAX"] > meta["_MIN"]:
        raise InputError("a modulo EEC table needs $AA_ENC_COMP_MAX > $AA_ENC_COMP_MIN",
                         file=eec_path)
    n = round((meta["_MAX"] - meta["_MIN"]) / meta["_STEP"]) + 1
    if sorted(values) != list(range(n)):
        raise InputError(f"expected compensation values 0..{n - 1} from _MIN, _MAX and _STEP, "
                         f"got {len(values)}", file=eec_path)
    nominal = meta["_MIN"] + meta["_STEP"] * np.arange(n)
    error = np.array([values[i] for i in range(n)])
    period = nominal[-1] - nominal[0] if meta.get("_IS_MODULO", 0) else None
    # the EEC value is the error: the control takes it off the position
    return Compensation(nominal, -error, -error, backlash, "siemens EEC", period)


def fanuc(path) -> Compensation:
    """Fanuc parameter sheet: 1851 backlash, 3620-3627 and incremental pitch-error values.

    The detection unit and the reference position are in ``um`` / ``mm`` (linear axis) or
    ``deg`` (rotary axis). With 3625 (movement per rotation, rotary-axis type) the table starts
    at the reference position (3621 = 3620), spans one rotation ((3622 - 3620) x 3624 = 3625)
    and repeats every rotation (0i-PB parameter manual B-63980EN, example 2). With ``3605#0 =
    1`` (bidirectional pitch error compensation) points 3621..3622 apply moving + and points
    3626..3626 + 3622 - 3621, at the same positions, moving -; the + table is 0 at the
    reference position, the - table is 3627 there (detection units; the writer's stated
    assumptions, ``pipeline.compensation.fanuc``).
    """
    params, pitch, unit, reference = _fanuc_sheet(path)
    backlash = params.get(1851, 0.0) * unit
    if not pitch:
        return Compensation(backlash_mm=backlash, source="fanuc 1851")
    both = params.get("3605#0", 0) == 1
    missing = [p for p in (3620, 3621, 3622, 3623, 3624, *((3626, 3627) if both else ()))
               if p not in params]
    if missing:
        raise InputError(f"missing parameter {missing[0]}", file=path)
    ref, low, high = (int(params[p]) for p in (3620, 3621, 3622))
    tables = [np.arange(low, high + 1)]
    if both:
        tables.append(int(params[3626]) + np.arange(high - low + 1))
    expected = sorted(int(p) for t in tables for p in t)
    if sorted(pitch) != expected or len(set(expected)) != len(expected) or not low <= ref <= high:
        raise InputError(f"expected pitch error values for points {low}..{high} around the "
                         f"reference point {ref}" + (f" and {tables[1][0]}..{tables[1][-1]} "
                                                     "(3626, travel in the - direction)"
                                                     if both else ""), file=path)
    period = _fanuc_rotation(params, path) * unit if params.get(3625) else None
    plus, *minus = (_fanuc_cumulative([pitch[p] for p in t], params[3623] * unit, ref - low)
                    for t in tables)
    minus = minus[0] + params[3627] * unit if both else plus
    nominal = reference + (tables[0] - ref) * params[3624] * unit
    return Compensation(nominal, plus, minus, backlash,
                        "fanuc bidirectional pitch error" if both else "fanuc pitch error", period)


def _fanuc_sheet(path) -> tuple[dict, dict, float | None, float | None]:
    """The settings of a Fanuc sheet: parameters (``NNNN`` as int, bits ``NNNN#b`` as text),
    pitch error values by point, the detection unit [mm, deg] and the reference position."""
    params, pitch, unit, reference = {}, {}, None, None
    for row, line in enumerate(file_text(path).splitlines(), start=1):
        line = line.split(";")[0].strip()
        if m := re.fullmatch(r"(\d{4})(#\d)?\s+\w+\s*=\s*(\S+)", line):
            key = f"{m[1]}{m[2]}" if m[2] else int(m[1])
            params[key] = finite_number(m[3], path, row, f"parameter {m[1]}{m[2] or ''}")
        elif m := re.fullmatch(r"PITCH\s+(\d+)\s*=\s*(\S+)", line):
            pitch[int(m[1])] = finite_number(m[2], path, row, f"pitch error point {m[1]}")
        elif m := re.fullmatch(r"DETECTION UNIT\s*=\s*(\S+)\s*(um|deg)", line):
            unit = finite_number(m[1], path, row, "detection unit") / (1000.0 if m[2] == "um"
                                                                        else 1.0)
        elif m := re.fullmatch(r"REFERENCE POSITION\s*=\s*(\S+)\s*(?:mm|deg)", line):
            reference = finite_number(m[1], path, row, "reference position")
    if unit is None or reference is None:
        raise InputError("missing 'DETECTION UNIT = ... um|deg' or 'REFERENCE POSITION = ... "
                         "mm|deg'", file=path)
    return params, pitch, unit, reference


def _fanuc_cumulative(values, step_mm: float, ref_index: int) -> np.ndarray:
    """The offset [mm] at each point of one table: the value of point N is output over the
    section from point N-1 to N (``step_mm`` per unit: detection unit x 3623); 0 at the
    reference point."""
    cumulative = np.cumsum(np.r_[0.0, np.asarray(values[1:], float)]) * step_mm
    return cumulative - cumulative[ref_index]


def _fanuc_rotation(params: dict, path) -> float:
    """3625, the movement per rotation [detection units] of a rotary-axis type table, checked
    against the table's layout (it starts at the reference and spans one rotation)."""
    ref, low, high, interval, rotation = (params[p] for p in (3620, 3621, 3622, 3624, 3625))
    if low != ref or not np.isclose((high - ref) * interval, rotation):
        raise InputError(f"3625 = {rotation:g}: a rotary-axis table needs 3621 = 3620 and "
                         "(3622 - 3620) x 3624 = 3625", file=path)
    return float(rotation)


def heidenhain(com_path, mp_path=None) -> Compensation:
    """Heidenhain ``.COM`` error table (``NR position error`` [mm]) and/or ``MP710`` backlash."""
    backlash = 0.0 if mp_path is None else _last_setting(
        mp_path, r"MP710\.\d+\s*=\s*(\S+)", "MP710")
    if com_path is None:
        return Compensation(backlash_mm=backlash, source="heidenhain MP710")
    rows = []
    for row, line in enumerate(file_text(com_path).splitlines(), start=1):
        parts = line.split(";")[0].split()
        if len(parts) == 3 and parts[0].isdigit():
            rows.append([finite_number(p, com_path, row, "compensation value") for p in parts[1:]])
    if not rows:
        raise InputError("no 'NR position error' lines", file=com_path)
    table = np.asarray(rows)
    _ascending(table[:, 0], com_path)
    return Compensation(table[:, 0], -table[:, 1], -table[:, 1], backlash, "heidenhain .COM")


def m425(path) -> Compensation:
    """Marlin / RepRapFirmware ``M425 X... `` backlash distance [mm] (first axis given)."""
    return _scalar_setting(path, r"M425\s+[XYZ](\S+).*", "M425", "no 'M425 X|Y|Z<mm>' line")


def grblhal(path) -> Compensation:
    """grblHAL ``$160-$162`` backlash [mm] (first setting given)."""
    return _scalar_setting(path, r"\$16[0-2]\s*=\s*(\S+)", "grblHAL",
                           "no '$160..$162=<mm>' line")


def _scalar_setting(path, pattern: str, source: str, missing: str) -> Compensation:
    """The first setting ``pattern`` matches is the backlash [mm] of a scalar-only controller."""
    value = next(_settings(path, pattern, source), None)
    if value is None:
        raise InputError(missing, file=path)
    return Compensation(backlash_mm=value, source=source)


def _last_setting(path, pattern: str, what: str) -> float:
    """The last setting ``pattern`` matches (the control reads its file top to bottom), else 0."""
    value = 0.0
    for value in _settings(path, pattern, what):
        pass
    return value


def _settings(path, pattern: str, what: str):
    """In file order, the value of each line ``pattern`` matches whole once ``;`` comments are
    cut (group 1, a finite number)."""
    for row, line in enumerate(file_text(path).splitlines(), start=1):
        if m := re.fullmatch(pattern, line.split(";")[0].strip()):
            yield finite_number(m[1], path, row, what)


def csv_table(path) -> Compensation:
    """The product's CSV: ``target_mm``, ``correction_plus_um``, ``correction_minus_um`` (a
    rotary axis's ``target_deg``, ``correction_plus_arcsec``, ``correction_minus_arcsec``:
    offsets in the table's position unit, arcsec / 3600 deg)."""
    import io

    import pandas as pd

    try:
        frame = pd.read_csv(io.StringIO(file_text(path)), comment="#")
    except (ValueError, pd.errors.ParserError) as err:
        raise InputError(f"not a CSV table: {str(err).splitlines()[0]}", file=path) from None
    rotary = "target_deg" in frame and "target_mm" not in frame
    need = (("target_deg", "correction_plus_arcsec", "correction_minus_arcsec") if rotary
            else ("target_mm", "correction_plus_um", "correction_minus_um"))
    values = {}
    for column in need:
        if column not in frame:
            raise InputError(f"missing column {column}", file=path, column=column)
        values[column] = pd.to_numeric(frame[column], errors="coerce").to_numpy(float)
        bad = ~np.isfinite(values[column])
        if bad.any():
            raise InputError("expected a finite number", file=path,
                             row=int(np.argmax(bad)) + 2, column=column)
    target, plus, minus = (values[c] for c in need)
    _ascending(target, path)
    scale = 3600.0 if rotary else 1000.0
    return Compensation(target, plus / scale, minus / scale, 0.0, "csv")


# Controller name -> reader of the files written for one machine axis: ``files`` maps a role
# (``table``, ``parameters``) to a path, as the writers return them.
READERS = {
    "linuxcnc": lambda files: linuxcnc(files.get("table"), files.get("parameters")),
    "siemens": lambda files: siemens(files.get("table"), files.get("parameters")),
    "fanuc": lambda files: fanuc(files.get("parameters") or files.get("table")),
    "heidenhain": lambda files: heidenhain(files.get("table"), files.get("parameters")),
    "marlin": lambda files: m425(files.get("parameters")),
    "reprap": lambda files: m425(files.get("parameters")),
    "grblhal": lambda files: grblhal(files.get("parameters")),
    "csv": lambda files: csv_table(files.get("table")),
}


def load(controller: str, files: dict) -> Compensation:
    """Parse the files written for one machine axis as ``controller`` reads them.

    Parameters
    ----------
    controller : str
        A name of ``READERS``.
    files : dict of str to path
        Role (``table``, ``parameters``) -> file, as the writers return them.

    Returns
    -------
    Compensation
        What the controller adds to the commanded position [mm].
    """
    if controller not in READERS:
        raise InputError(f"unknown controller {controller!r}; expected one of "
                         f"{', '.join(READERS)}", parameter="controller")
    return READERS[controller](files)
