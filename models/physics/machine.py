"""The three-axis machine twin: 21 geometric errors, Abbe offsets and three feed drives.

A vertical machining centre of the seed paper's kind [Chen2022]_ (XHK714, "XYTZ"): the
workpiece rides on the X table, the X table on the Y saddle, the saddle on the bed; the tool
rides on the Z ram. Each axis k carries six error motions of its position q_k, stated at its
scale's reading head R_k (the point the control measures): three translations delta_k(q_k)
[um] (positioning and two straightness) and three angles eps_k(q_k) [urad] (roll, pitch,
yaw). Three squareness errors [urad] tilt the Y and Z directions of motion:
d_Y = e_y + a_XY e_x, d_Z = e_z + a_XZ e_x + a_YZ e_y.

The kinematic chain is composed of small-angle homogeneous transforms (``chain_error_um``),
each carriage turning about the material point at its reading head: bed -> Y -> X ->
workpiece and bed -> Z -> tool. To first order (``tool_error_um``) the error of a point h
carried by the spindle (tool tip, or the laser's optics) relative to the workpiece, with the
machine at P = (x, y, z), is

    E(P, h) = - sum_{k=X,Y} [delta_k(q_k) + eps_k(q_k) x (h + z e_z - R_k)]
              + delta_Z(z) + eps_Z(z) x (h - R_Z) + (a_XY y + a_XZ z, a_YZ z, 0)

(the paper's equation (1) and (3): the lever of an angle is the Abbe offset from the reading
head to the point, so a laser line off the tool point sees angle x its own offset, not the
tool's).

Three feed drives turn the commanded path into carriage positions: a servo lag (first order,
time constant T: at steady feed the carriage trails by velocity x T), a play of width b on the
motor's path (``models.physics.axis.play``) and a friction spike of height h after each
reversal, decaying over a distance lambda of travel. Static tests (ISO 230-2 lines, ISO 230-6
diagonals) read at rest, where the lag has settled; circles (ISO 230-4) read on the move.

Units: positions and offsets in mm, translations in um, angles in urad (um/m).

References
----------
.. [Chen2022] G. Chen et al. (seed 001), "Modeling Method of CNC Machine Tools' Volume Error Considering
   Abbe Error" (equations (1)-(4), Table 1).
.. ISO 230-1 (geometric accuracy), ISO 230-2 (positioning), ISO 230-4 (circular tests),
   ISO 230-6 (body diagonals).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from models.physics.axis import play

AXES = ("X", "Y", "Z")
TABLE_AXES = ("X", "Y")  # carry the workpiece: their errors enter with a minus sign
CHANNELS = ("dx_um", "dy_um", "dz_um", "ex_urad", "ey_urad", "ez_urad")
SQUARENESS = ("XY", "XZ", "YZ")
PLANES = {"XY": (0, 1), "YZ": (1, 2), "ZX": (2, 0)}  # first axis along 0 deg
CIRCLE_COLUMNS = ("test_id", "machine_id", "plane", "direction", "angle_deg", "radius_mm",
                  "feed_mm_min", "deviation_um")
UM, URAD = 1e-3, 1e-6  # [mm/um], [rad/urad]


@dataclass(frozen=True)
class ErrorTable:
    """The six error motions of one axis, tabulated along its travel and interpolated.

    Attributes
    ----------
    position_mm : ndarray, shape (m,)
        Ascending positions of the table [mm].
    values : ndarray, shape (m, 6)
        delta_x, delta_y, delta_z [um] and eps_x, eps_y, eps_z [urad] at each position
        (``CHANNELS``). Outside the table the end values hold.
    """

    position_mm: np.ndarray
    values: np.ndarray

    def __call__(self, q_mm) -> np.ndarray:
        q = np.asarray(q_mm, float)
        return np.stack([np.interp(q, self.position_mm, self.values[:, j]) for j in range(6)],
                        axis=-1)


@dataclass(frozen=True)
class Geometry:
    """The 21 geometric errors of a three-axis machine and where its scales read.

    Attributes
    ----------
    errors : dict of str to ErrorTable
        Axis -> its six error motions, stated at its reading head.
    squareness_urad : dict of str to float
        'XY', 'XZ', 'YZ' -> a [urad]: the second axis' direction leans by a towards the first.
    reading_head_mm : dict of str to ndarray
        Axis -> R_k [mm]: for X and Y in the bed's frame (with z = 0 at the spindle reference),
        for Z relative to the spindle reference point.
    travel_mm : dict of str to tuple
        Axis -> (low, high) [mm].
    """

    errors: dict
    squareness_urad: dict
    reading_head_mm: dict
    travel_mm: dict

    def motion(self, axis: str, q_mm) -> tuple[np.ndarray, np.ndarray]:
        """delta [um] and eps [urad] of ``axis`` at ``q_mm``, each shape (n, 3)."""
        six = self.errors[axis](q_mm)
        return six[..., :3], six[..., 3:]


@dataclass(frozen=True)
class FeedDrive:
    """One axis' feed drive.

    Attributes
    ----------
    backlash_um : float
        Width b of the play between motor and carriage [um].
    spike_um : float
        Height of the friction spike after a reversal [um]: the carriage sticks against its
        new direction of motion.
    spike_mm : float
        Travel over which the spike decays by 1/e [mm].
    servo_ms : float
        Servo time constant T [ms]: at steady velocity v the carriage trails by v T.
    """

    backlash_um: float = 0.0
    spike_um: float = 0.0
    spike_mm: float = 1.0
    servo_ms: float = 0.0


@dataclass(frozen=True)
class Machine:
    """The twin: geometry, the tool point on the spindle and the three feed drives.

    Attributes
    ----------
    geometry : Geometry
    tool_mm : ndarray, shape (3,)
        The tool point relative to the spindle reference point [mm].
    drives : dict of str to FeedDrive
    machine_id : str
    """

    geometry: Geometry
    tool_mm: np.ndarray
    drives: dict = field(default_factory=lambda: {a: FeedDrive() for a in AXES})
    machine_id: str = "twin"


def cross_um(eps_urad: np.ndarray, lever_mm: np.ndarray) -> np.ndarray:
    """eps x lever [um] for eps [urad] and lever [mm]: urad x mm = 1e-3 um."""
    return np.cross(eps_urad, lever_mm) * 1e-3


def tool_error_um(geometry: Geometry, position_mm, point_mm) -> np.ndarray:
    """First-order error of a spindle point relative to the workpiece [um], shape (n, 3).

    E(P, h) = -sum_{k=X,Y} [delta_k + eps_k x (h + z e_z - R_k)] + delta_Z + eps_Z x (h - R_Z)
    + (a_XY y + a_XZ z, a_YZ z, 0)  [Chen2022]_ eq. (1), (3).

    Parameters
    ----------
    geometry : Geometry
    position_mm : array-like, shape (n, 3)
        Nominal machine positions (x, y, z) [mm].
    point_mm : array-like, shape (3,) or (n, 3)
        The point h on the spindle relative to its reference point [mm] (tool tip or optics).
    """
    p = np.atleast_2d(np.asarray(position_mm, float))
    h = np.broadcast_to(np.asarray(point_mm, float), p.shape)
    z_lever = np.zeros_like(p)
    z_lever[:, 2] = p[:, 2]
    error = np.zeros_like(p)
    for i, axis in enumerate(AXES):
        delta, eps = geometry.motion(axis, p[:, i])
        if axis in TABLE_AXES:
            error -= delta + cross_um(eps, h + z_lever - geometry.reading_head_mm[axis])
        else:
            error += delta + cross_um(eps, h - geometry.reading_head_mm[axis])
    a = geometry.squareness_urad
    error[:, 0] += 1e-3 * (a["XY"] * p[:, 1] + a["XZ"] * p[:, 2])
    error[:, 1] += 1e-3 * a["YZ"] * p[:, 2]
    return error


def _about(pivot_mm: np.ndarray, eps_urad: np.ndarray, move_mm: np.ndarray) -> np.ndarray:
    """Homogeneous transforms (n, 4, 4): move by ``move_mm``, then turn by the small angles
    ``eps_urad`` about ``pivot_mm``: p -> pivot + (I + [eps]x)(p + move - pivot)."""
    e = eps_urad * URAD
    n = len(e)
    rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    rot[:, 0, 1], rot[:, 0, 2] = -e[:, 2], e[:, 1]
    rot[:, 1, 0], rot[:, 1, 2] = e[:, 2], -e[:, 0]
    rot[:, 2, 0], rot[:, 2, 1] = -e[:, 1], e[:, 0]
    frame = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    frame[:, :3, :3] = rot
    frame[:, :3, 3] = pivot_mm + np.einsum("nij,nj->ni", rot, move_mm - pivot_mm)
    return frame


def _directions(geometry: Geometry) -> dict:
    a = geometry.squareness_urad
    return {"X": np.array([1.0, 0.0, 0.0]),
            "Y": np.array([a["XY"] * URAD, 1.0, 0.0]),
            "Z": np.array([a["XZ"] * URAD, a["YZ"] * URAD, 1.0])}


def chain_transform(geometry: Geometry, position_mm) -> np.ndarray:
    """The spindle's frame in the workpiece's frame, (n, 4, 4): W^-1 T_Z with W = T_Y T_X.

    Each carriage moves along its direction (the tables by -q, so that the tool moves by +q
    relative to the workpiece), is displaced by delta and turned by eps about its reading head,
    a point fixed in its parent's frame [Chen2022]_ section 1.
    """
    p = np.atleast_2d(np.asarray(position_mm, float))
    d = _directions(geometry)
    heads = geometry.reading_head_mm
    (dx, ex), (dy, ey), (dz, ez) = (geometry.motion(a, p[:, i]) for i, a in enumerate(AXES))
    x, y, z = (p[:, [i]] for i in range(3))
    t_y = _about(np.broadcast_to(heads["Y"], p.shape), ey, -y * d["Y"] + dy * UM)
    # X's reading head is fixed in the bed: in the saddle's frame it sits at R_X + y d_Y
    t_x = _about(heads["X"] + y * d["Y"], ex, -x * d["X"] + dx * UM)
    t_z = _about(heads["Z"] + z * d["Z"], ez, z * d["Z"] + dz * UM)
    return np.linalg.solve(t_y @ t_x, t_z)


def chain_error(geometry: Geometry, position_mm, point_mm) -> tuple[np.ndarray, np.ndarray]:
    """The error of a spindle point relative to the workpiece from the full chain of
    homogeneous transforms: translation [um] and the relative angles of the spindle [urad],
    each shape (n, 3). Agrees with ``tool_error_um`` to second order in the errors."""
    p = np.atleast_2d(np.asarray(position_mm, float))
    h = np.broadcast_to(np.asarray(point_mm, float), p.shape)
    frame = chain_transform(geometry, p)
    moved = np.einsum("nij,nj->ni", frame[:, :3, :3], h) + frame[:, :3, 3]
    rot = frame[:, :3, :3]
    angles = np.stack([rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0],
                       rot[:, 1, 0] - rot[:, 0, 1]], axis=1) / 2.0 / URAD
    return (moved - h - p) / UM, angles


# ------------------------------------------------------------------------- feed drives
def _spike_um(commanded_mm: np.ndarray, drive: FeedDrive) -> np.ndarray:
    """The friction spike along one axis' commanded path [um]: -s h exp(-d / lambda) after
    each reversal, s the new direction, d the travel since the reversal (none before the first)."""
    if drive.spike_um == 0:
        return np.zeros_like(commanded_mm)
    step = np.diff(commanded_mm, prepend=commanded_mm[0])
    moving = np.sign(step)
    # direction of the last move at each sample (held through stops)
    index = np.where(moving != 0, np.arange(len(step)), 0)
    sense = moving[np.maximum.accumulate(index)]
    reversal = np.r_[False, (sense[1:] * sense[:-1]) < 0]
    travelled = np.cumsum(np.abs(step))
    last = np.maximum.accumulate(np.where(reversal, np.arange(len(step)), -1))
    # the turning point is the sample before the first step of the new direction
    since = np.where(last >= 0, travelled - travelled[np.maximum(last - 1, 0)], np.inf)
    return -sense * drive.spike_um * np.exp(-since / drive.spike_mm)


def _servo(commanded_mm: np.ndarray, time_s: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order lag of a piecewise-linear command, exact per step: the tracking error
    e = c - p obeys de/dt = v - e / T, so e_k = v T + (e_(k-1) - v T) exp(-dt / T)."""
    if tau_s <= 0:
        return commanded_mm.copy()
    dt = np.diff(time_s)
    v = np.diff(commanded_mm) / np.where(dt > 0, dt, np.inf)
    decay = np.exp(-dt / tau_s)
    e = np.zeros_like(commanded_mm)
    for k in range(1, len(e)):
        e[k] = v[k - 1] * tau_s + (e[k - 1] - v[k - 1] * tau_s) * decay[k - 1]
    return commanded_mm - e


def drive_positions(machine: Machine, commanded_mm: np.ndarray, time_s=None) -> np.ndarray:
    """Carriage positions [mm], shape (n, 3), for a commanded path (n, 3) [mm]: servo lag
    (when ``time_s`` [s] is given; at rest it has settled), play, friction spike."""
    out = np.empty_like(commanded_mm, dtype=float)
    for i, axis in enumerate(AXES):
        drive = machine.drives[axis]
        c = commanded_mm[:, i]
        motor = c if time_s is None else _servo(c, np.asarray(time_s, float),
                                                drive.servo_ms / 1000.0)
        table = play(motor[None, :], np.array([[drive.backlash_um]]))[0]
        out[:, i] = table + _spike_um(c, drive) * UM
    return out


# ------------------------------------------------------------------------- tests
def _compensated(command_mm: np.ndarray, compensation) -> np.ndarray:
    """The command a compensating control sends for the wanted positions: P - E_model(P),
    iterated once more at the corrected command (the model is evaluated where the axes go)."""
    if compensation is None:
        return command_mm
    sent = command_mm - compensation(command_mm) * UM
    return command_mm - compensation(sent) * UM


def line_test(machine: Machine, start_mm, end_mm, *, targets: int = 11, cycles: int = 1,
              point_mm=None, bidirectional: bool = True, overshoot_mm: float = 5.0,
              noise=None, rng=None, compensation=None) -> pd.DataFrame:
    """An ISO 230-2 test along any line, read by a six-channel laser at a spindle point.

    The axes move together from ``start_mm`` to ``end_mm`` through equally spaced targets, each
    approached in the run's direction after an overshoot (linear cycle, ISO 230-2), reading at
    rest; the laser reads the point's error relative to the workpiece (three translations and
    three angles), zeroed at the first target of the first run.

    Parameters
    ----------
    machine : Machine
    start_mm, end_mm : array-like, shape (3,)
        Ends of the line (x, y, z) [mm].
    targets, cycles : int
        Targets along the line; cycles (one run forward and, if ``bidirectional``, one back).
    point_mm : array-like, shape (3,), optional
        Where the optics sit relative to the spindle reference [mm]; default the tool point.
    noise : dict, optional
        Standard deviations of the readings by channel name (``CHANNELS``).
    rng : numpy.random.Generator, optional
        For the noise.
    compensation : callable, optional
        P (n, 3) [mm] -> the model's tool error [um]; the control subtracts it from the command.

    Returns
    -------
    DataFrame
        One row per reading: ``cycle``, ``direction`` (+1 forward), ``target`` (index),
        ``distance_mm`` along the line, ``x_mm``, ``y_mm``, ``z_mm`` (nominal), the six
        ``CHANNELS`` and ``deviation_um`` (the translation along the line).
    """
    start, end = np.asarray(start_mm, float), np.asarray(end_mm, float)
    length = float(np.linalg.norm(end - start))
    unit = (end - start) / length
    s = np.linspace(0.0, length, targets)
    runs = [(+1, s)] + ([(-1, s[::-1])] if bidirectional else [])
    waypoints, rows = [], []
    for cycle in range(1, cycles + 1):
        for direction, order in runs:
            waypoints.append(order[0] - direction * overshoot_mm)  # approach, not read
            rows.append(None)
            for j, d in zip(range(targets) if direction > 0 else range(targets)[::-1], order):
                waypoints.append(d)
                rows.append((cycle, direction, j, d))
    wanted = start + np.outer(waypoints, unit)
    carriage = drive_positions(machine, _compensated(wanted, compensation))
    point = machine.tool_mm if point_mm is None else np.asarray(point_mm, float)
    trans, angles = chain_error(machine.geometry, carriage, point)
    read = np.array([r is not None for r in rows])
    # what the laser sees: the point's true place minus where it was sent
    seen = np.hstack([trans + (carriage - wanted) / UM, angles])[read]
    seen -= seen[0]
    if noise:
        rng = rng if rng is not None else np.random.default_rng(0)
        sd = np.array([noise.get(c, 0.0) for c in CHANNELS])
        seen = seen + rng.normal(size=seen.shape) * sd
    frame = pd.DataFrame([r for r in rows if r is not None],
                         columns=["cycle", "direction", "target", "distance_mm"])
    frame[["x_mm", "y_mm", "z_mm"]] = wanted[read]
    frame[list(CHANNELS)] = seen
    frame["deviation_um"] = seen[:, :3] @ unit
    return frame


def as_readings(test: pd.DataFrame, *, machine_id: str, axis: str, test_id: str,
                start_mm: float = 0.0) -> pd.DataFrame:
    """A ``line_test`` frame as the readings table (data contract section 1, linear cycle):
    targets at ``start_mm`` + the distance along the line [mm], directions '+' and '-', the deviation
    along the line [um]; the rest of the product (``iso``, ``targets``) reads it as a laser's."""
    return pd.DataFrame({
        "machine_id": machine_id, "axis": axis, "test_id": test_id, "method": "linear",
        "target": (start_mm + test["distance_mm"]).round(6),
        "direction": np.where(test["direction"] > 0, "+", "-"), "cycle": test["cycle"],
        "deviation_um": test["deviation_um"]})


def body_diagonals(travel_mm: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The four ISO 230-6 body diagonals of the working volume, by the signs of their x, y, z
    steps as the seed paper names them: PPP, NPP, PPN, NPN -> (start, end) [mm]."""
    lo = np.array([travel_mm[a][0] for a in AXES], float)
    hi = np.array([travel_mm[a][1] for a in AXES], float)
    out = {}
    for name in ("PPP", "NPP", "PPN", "NPN"):
        forward = np.array([c == "P" for c in name])
        out[name] = (np.where(forward, lo, hi), np.where(forward, hi, lo))
    return out


def circle_test(machine: Machine, *, plane: str = "XY", radius_mm: float = 100.0,
                feed_mm_min: float = 1000.0, direction: str = "CCW", center_mm=None,
                points: int = 360, oversample: int = 4, test_id: str | None = None) -> pd.DataFrame:
    """An ISO 230-4 circular test (ballbar) in any plane: the radial deviation of the tool
    from a centre fixed on the workpiece, read on the move.

    The ballbar's centre pivot is set where the tool stands when sent to ``center_mm``. The
    circle is commanded from 0 deg after a half-turn lead-in (so the lag and the play have
    settled) at ``feed_mm_min``; the feed drives turn it into carriage positions, the geometry
    into the tool's place relative to the workpiece. An axis reverses where the circle is
    tangent to the other axis: the first axis at 0 and 180 deg, the second at 90 and 270 deg.

    Parameters
    ----------
    plane : {'XY', 'YZ', 'ZX'}
        The plane; its first letter is the axis along 0 deg, angles grow towards the second.
    radius_mm : float
        Nominal radius [mm].
    feed_mm_min : float
        Feed along the path [mm/min].
    direction : {'CCW', 'CW'}
        CCW runs towards growing angles.
    center_mm : array-like, shape (3,), optional
        Centre [mm]; default the middle of the travel.
    points : int
        Readings per revolution, equally spaced in time.
    oversample : int
        Simulation steps per reading.
    test_id : str, optional

    Returns
    -------
    DataFrame
        data contract section 11's columns: ``test_id``, ``machine_id``, ``plane``, ``direction``,
        ``angle_deg`` (0 to 360, the nominal angle of the reading), ``radius_mm``,
        ``feed_mm_min``, ``deviation_um`` (measured minus nominal radius).
    """
    first, second = PLANES[plane]
    geometry = machine.geometry
    center = (np.array([np.mean(geometry.travel_mm[a]) for a in AXES]) if center_mm is None
              else np.asarray(center_mm, float))
    sense = 1.0 if direction == "CCW" else -1.0
    steps = points * oversample
    theta = sense * np.radians(np.arange(-steps // 2, steps + 1) * 360.0 / steps)
    command = np.tile(center, (len(theta), 1))
    command[:, first] += radius_mm * np.cos(theta)
    command[:, second] += radius_mm * np.sin(theta)
    time_s = np.abs(theta - theta[0]) * radius_mm / (feed_mm_min / 60.0)
    carriage = drive_positions(machine, command, time_s)
    tool, _ = chain_error(geometry, carriage, machine.tool_mm)
    actual = carriage + tool * UM
    read = slice(steps // 2, steps // 2 + steps, oversample)
    # the centre pivot is set where the tool stands when sent to the centre (ISO 230-4 setup)
    pivot = center + chain_error(geometry, center, machine.tool_mm)[0][0] * UM
    deviation = (np.linalg.norm(actual[read] - pivot, axis=1) - radius_mm) / UM
    return pd.DataFrame({
        "test_id": test_id or f"{machine.machine_id}-{plane}-{direction}",
        "machine_id": machine.machine_id, "plane": plane, "direction": direction,
        "angle_deg": np.degrees(theta[read]) % 360.0, "radius_mm": float(radius_mm),
        "feed_mm_min": float(feed_mm_min), "deviation_um": deviation})[list(CIRCLE_COLUMNS)]


# ------------------------------------------------------------------------- the paper's machine
def _shape(u: np.ndarray, terms) -> np.ndarray:
    """A smooth error shape on u in [0, 1]: a sum of (amplitude, cycles, phase) sines."""
    return sum(a * np.sin(2 * np.pi * c * u + p) for a, c, p in terms)


# Per axis, per channel: (low, high) of the error over the travel [um or urad], sized on the
# paper's Figure 5 ranges (section 3.1.1), and a shape: sines of (weight, cycles, phase).
PAPER_ERRORS = {
    "X": {"dx_um": ((-40.2, 65.6), ((1.0, 0.55, 0.3), (0.25, 1.3, 1.0))),
          "dy_um": ((-14.4, 11.9), ((1.0, 0.9, 0.4), (0.3, 1.7, 0.0))),
          "dz_um": ((-12.0, 10.0), ((1.0, 0.7, 2.0), (0.2, 1.9, 0.5))),
          "ex_urad": ((-7.1, 9.7), ((1.0, 0.6, 0.8), (0.2, 1.5, 0.2))),
          "ey_urad": ((-7.1, 9.7), ((1.0, 0.8, 0.1), (0.3, 1.4, 1.2))),
          "ez_urad": ((-6.0, 8.0), ((1.0, 0.5, 1.5), (0.2, 1.6, 0.7)))},
    "Y": {"dx_um": ((-18.5, 22.5), ((1.0, 0.8, 0.9), (0.3, 1.6, 0.1))),
          "dy_um": ((-24.1, -0.2), ((1.0, 0.45, 0.2), (0.2, 1.2, 0.4))),
          "dz_um": ((-15.0, 18.0), ((1.0, 0.6, 1.1), (0.25, 1.8, 0.3))),
          "ex_urad": ((-41.4, 2.7), ((1.0, 0.5, 0.6), (0.2, 1.3, 0.9))),
          "ey_urad": ((-30.0, 2.0), ((1.0, 0.55, 1.3), (0.3, 1.1, 0.2))),
          "ez_urad": ((-20.0, 2.7), ((1.0, 0.4, 0.5), (0.2, 1.5, 1.4)))},
    "Z": {"dx_um": ((-77.2, 68.8), ((1.0, 0.7, 0.2), (0.3, 1.4, 0.8))),
          "dy_um": ((-30.8, 44.2), ((1.0, 0.85, 1.0), (0.2, 1.7, 0.3))),
          "dz_um": ((0.2, 41.7), ((1.0, 0.5, 0.4), (0.2, 1.2, 1.1))),
          "ex_urad": ((-5.7, 68.9), ((1.0, 0.45, 0.9), (0.25, 1.3, 0.4))),
          "ey_urad": ((-5.7, 50.0), ((1.0, 0.6, 0.3), (0.2, 1.5, 1.0))),
          "ez_urad": ((-5.0, 30.0), ((1.0, 0.5, 1.2), (0.3, 1.6, 0.6)))},
}
PAPER_TRAVEL_MM = {"X": (0.0, 1500.0), "Y": (-2550.0, -1050.0), "Z": (-900.0, 200.0)}
PAPER_SQUARENESS_URAD = {"XY": 12.0, "XZ": -15.0, "YZ": 9.0}  # not in the paper: plausible
# Reading heads (not in the paper): the table scales low at the front and side of the bed, the
# Z scale on the column behind the spindle; z = 0 at the spindle reference.
PAPER_READING_HEAD_MM = {"X": np.array([0.0, -300.0, -1150.0]),
                         "Y": np.array([-450.0, 0.0, -1200.0]),
                         "Z": np.array([0.0, 350.0, 0.0])}
PAPER_TOOL_MM = np.array([0.0, 0.0, -200.0])  # tool tip below the spindle reference
PAPER_DRIVES = {"X": FeedDrive(backlash_um=6.0, spike_um=4.0, spike_mm=1.5, servo_ms=30.0),
                "Y": FeedDrive(backlash_um=4.0, spike_um=3.0, spike_mm=1.5, servo_ms=30.5),
                "Z": FeedDrive(backlash_um=8.0, spike_um=5.0, spike_mm=1.0, servo_ms=31.0)}


def _scaled(axis_values: dict, u: np.ndarray) -> np.ndarray:
    """Each channel's shape stretched to its (low, high) range, shape (m, 6)."""
    columns = []
    for channel in CHANNELS:
        (low, high), terms = axis_values[channel]
        raw = _shape(u, terms)
        columns.append(low + (raw - raw.min()) / np.ptp(raw) * (high - low))
    return np.stack(columns, axis=1)


def paper_machine(machine_id: str = "XHK714-twin", samples: int = 1501) -> Machine:
    """The seed paper's machine as a twin: its travels, its errors sized on its Figure 5 ranges
    (smooth shapes of our choosing: the paper plots but does not tabulate them), squareness,
    reading heads, tool point and feed drives of plausible size (the paper gives none)."""
    errors = {}
    for axis in AXES:
        lo, hi = PAPER_TRAVEL_MM[axis]
        u = np.linspace(0.0, 1.0, samples)
        values = _scaled(PAPER_ERRORS[axis], u)
        errors[axis] = ErrorTable(lo + u * (hi - lo), conventional(axis, values, u))
    geometry = Geometry(errors=errors, squareness_urad=dict(PAPER_SQUARENESS_URAD),
                        reading_head_mm=dict(PAPER_READING_HEAD_MM),
                        travel_mm=dict(PAPER_TRAVEL_MM))
    return Machine(geometry=geometry, tool_mm=PAPER_TOOL_MM.copy(), drives=dict(PAPER_DRIVES),
                   machine_id=machine_id)


def conventional(axis: str, values: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Error motions (m, 6) along u in [0, 1] in ISO 230-1's conventions: positioning and the
    angles zero at the start of travel (the start defines the axis' frame), the two
    straightness errors with their least-squares line removed (a line is squareness or
    alignment, kept in ``squareness_urad``)."""
    out = values - values[0]
    j = AXES.index(axis)
    for c in range(3):
        if c != j:
            slope, offset = np.polyfit(u, values[:, c], 1)
            out[:, c] = values[:, c] - (slope * u + offset)
    return out


def without(machine: Machine, *, geometry: bool = False, drives: bool = False) -> Machine:
    """A copy of ``machine`` with its geometric errors and/or its feed drives removed."""
    g = machine.geometry
    if geometry:
        g = replace(g, errors={a: ErrorTable(np.array(g.travel_mm[a], float), np.zeros((2, 6)))
                               for a in AXES},
                    squareness_urad={k: 0.0 for k in SQUARENESS})
    d = {a: FeedDrive() for a in AXES} if drives else machine.drives
    return replace(machine, geometry=g, drives=d)
