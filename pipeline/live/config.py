"""WATCH.toml (data contract section 14): the source and the machine axes it feeds."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from features.readings.errors import InputError
from features.readings.schema import LINEAR_AXES, ROTARY_AXES

PROTOCOLS = ("ca", "pva", "opcua", "log")
CHANNELS = ("commanded", "motor", "load")
# Under an OPC 40502 CncAxisType node: the commanded position, the motor-side (indirect)
# and the load-side (direct) measuring systems' actual positions.
AXIS_NODE = {"commanded": "CmdPos", "motor": "PosIndirect/ActPos", "load": "PosDirect/ActPos"}
# How long a source may take to answer at start before watch gives up [s].
TIMEOUT_S = 10.0
# An axis silent longer than its stale_after_s [s] is stale in fleet (``source_stale``);
# without one, fleet's stale_after_days applies.
STALE_AFTER_S = None


@dataclass
class AxisConfig:
    machine_id: str
    axis: str
    channels: dict  # channel -> PV, node id or browse path
    gain: float = 1.0  # load = gain * received + offset (monitor's --reference-scale)
    offset: float = 0.0
    stale_after_s: float | None = STALE_AFTER_S

    @property
    def key(self) -> str:
        return f"{self.machine_id}/{self.axis}"


@dataclass
class WatchConfig:
    protocol: str
    address: str
    axes: list = field(default_factory=list)
    timeout_s: float = TIMEOUT_S
    period_s: float | None = None  # the source's nominal sample period, for the coverage
    path: str = ""


def read_config(path) -> WatchConfig:
    """The checked configuration; one ``InputError`` naming the file otherwise."""
    path = Path(path)

    def fail(message: str):
        raise InputError(message, file=str(path), parameter="config")

    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        fail("no such file; expected a WATCH.toml")
    except (OSError, UnicodeDecodeError) as err:
        fail(f"cannot read it: {err}")
    except tomllib.TOMLDecodeError as err:
        fail(f"is not TOML: {err}")
    source = data.get("source")
    if not isinstance(source, dict):
        fail("has no [source] table; expected protocol and address")
    protocol = source.get("protocol")
    if protocol not in PROTOCOLS:
        fail(f"protocol {protocol!r} is unknown; expected one of {', '.join(PROTOCOLS)}")
    address = source.get("address")
    if not isinstance(address, str) or not address.strip():
        fail("[source] has no address; expected the server's address or the log file")
    if protocol == "log" and not Path(address).is_absolute():
        address = str(path.parent / address)
    timeout = _positive(source.get("timeout_s", TIMEOUT_S), "timeout_s", fail)
    period = source.get("period_s")
    period = None if period is None else _positive(period, "period_s", fail)
    entries = data.get("axis")
    if not isinstance(entries, list) or not entries:
        fail("has no [[axis]] table; expected one per machine axis")
    axes, seen, owner = [], set(), {}
    for i, entry in enumerate(entries, 1):
        axes.append(_axis(entry, i, fail, protocol))
        a = axes[-1]
        if a.key in seen:
            fail(f"machine {a.machine_id} axis {a.axis} is given twice")
        seen.add(a.key)
        for name in sorted(set(a.channels.values())):
            if name in owner:
                fail(f"channel {name!r} feeds two axes ({owner[name]} and {a.key}); expected "
                     "each axis its own channels")
            owner[name] = a.key
    return WatchConfig(protocol, address.strip(), axes, timeout, period, str(path))


def _axis(entry, i: int, fail, protocol: str = "") -> AxisConfig:
    if not isinstance(entry, dict):
        fail(f"[[axis]] {i} is not a table")
    machine, axis = entry.get("machine_id"), entry.get("axis")
    node = entry.get("node")
    if node is not None:
        # an OPC 40502 CncAxisType node: its set point and its two position feedbacks
        if protocol != "opcua" or not isinstance(node, str) or not node.strip():
            fail(f"[[axis]] {i}: node {node!r} is for an opcua source (an OPC 40502 axis)")
        if any(name in entry for name in CHANNELS):
            fail(f"[[axis]] {i}: give node or the channels, not both")
        entry = {**entry, **{name: f"{node.strip().rstrip('/')}/{path}"
                             for name, path in AXIS_NODE.items()}}
    if not isinstance(machine, str) or not machine.strip():
        fail(f"[[axis]] {i} has no machine_id")
    if axis not in (*LINEAR_AXES, *ROTARY_AXES):
        fail(f"[[axis]] {i}: axis {axis!r} is unknown; expected one of "
             f"{', '.join((*LINEAR_AXES, *ROTARY_AXES))}")
    channels = {}
    for name in CHANNELS:
        value = entry.get(name)
        if not isinstance(value, str) or not value.strip():
            fail(f"[[axis]] {i} ({machine} {axis}) has no {name} channel"
                 + ("; lost motion needs a load-side position" if name == "load" else ""))
        channels[name] = value.strip()
    known = {"machine_id", "axis", *CHANNELS, "node", "reference_scale", "stale_after_s"}
    unknown = sorted(set(entry) - known)
    if unknown:
        fail(f"[[axis]] {i} ({machine} {axis}): unknown key {unknown[0]!r}; expected "
             f"{', '.join(sorted(known))}")
    gain, offset = 1.0, 0.0
    if "reference_scale" in entry:
        from features.traces.logs import _scale

        try:
            gain, offset = _scale(entry["reference_scale"])
        except InputError as err:
            fail(f"[[axis]] {i}: reference_scale {err.message}")
    stale = entry.get("stale_after_s", STALE_AFTER_S)
    stale = None if stale is None else _positive(stale, "stale_after_s", fail)
    return AxisConfig(machine.strip(), axis, channels, gain, offset, stale)


def _positive(value, name: str, fail) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0):
        fail(f"{name} is {value!r}; expected a number of seconds > 0")
    return float(value)
