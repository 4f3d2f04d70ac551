"""The protocols: each source calls ``emit(name, ns, value)`` per channel update with the
server's timestamp [ns since the epoch, UTC], reconnects with backoff when the server goes
away, and raises ``InputError`` when it never answers at start (within ``timeout_s``).

- ``log``: a camonitor file being appended to; follows rotation (a new file at the path) and
  truncation (the file shorter than what was read), resuming at a saved offset;
- ``ca``: EPICS Channel Access, caproto's pure-Python asyncio client;
- ``pva``: EPICS PV Access, p4p's asyncio client;
- ``opcua``: OPC UA (asyncua), node ids or OPC 40502 CncAxisType browse paths.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import os

from features.readings.errors import InputError

# Backoff between reconnection attempts [s]: doubled each time, up to the last.
BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0)
POLL_S = 0.05
EPICS_EPOCH_S = 631_152_000  # 1990-01-01 in Unix seconds
UNITS = {"linear": ("mm", ""), "rotary": ("deg", "degree", "degrees", "°", "")}


class LogSource:
    """A camonitor log as it grows (``offset``/``inode`` are its resumable state).

    The file stays open, as ``tail -F`` keeps it: at a rotation (a new file at the path) what
    was appended to the old one is read to its end first, so nothing is lost; at a truncation
    (the file shorter than what was read) it is read again from its start. After either,
    a line no later than the last one taken from its PV was taken before the file was
    rewritten, and is skipped, so nothing is doubled."""

    def __init__(self, config, emit, status):
        self.path, self.emit, self.status = config.address, emit, status
        self.names = {n for a in config.axes for n in a.channels.values()}
        self.offset, self.inode, self.handle = 0, None, None
        self.last: dict = {}  # PV -> time of its last line taken [ns]
        self.resync: set = set()  # PVs whose lines may repeat what was taken

    def state(self) -> dict:
        return {"offset": self.offset, "inode": self.inode, "last": self.last,
                "resync": sorted(self.resync)}

    def restore(self, state: dict) -> None:
        self.offset, self.inode = int(state.get("offset", 0)), state.get("inode")
        self.last = {k: int(v) for k, v in state.get("last", {}).items()}
        self.resync = set(state.get("resync", ()))

    async def start(self, timeout_s: float) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not os.path.exists(self.path):
            if loop.time() > deadline:
                raise InputError(f"the log {self.path} does not exist after {timeout_s:g} s; "
                                 "expected a camonitor file being written", parameter="config")
            await asyncio.sleep(POLL_S)

    async def run(self) -> None:
        while True:
            self.poll()
            await asyncio.sleep(POLL_S)

    async def close(self) -> None:
        if self.handle is not None:
            self.handle.close()
            self.handle = None

    def _open(self) -> bool:
        try:
            self.handle = open(self.path, "rb")  # noqa: SIM115 - kept open across polls
        except FileNotFoundError:
            return False  # between a rotation's rename and the new file
        inode = os.fstat(self.handle.fileno()).st_ino
        if self.inode is not None and inode != self.inode:  # rotated while no watcher ran
            self._rewritten("log_rotated")
        self.inode = inode
        return True

    def _rewritten(self, event: str) -> None:
        self.status({"event": event, "path": self.path})
        self.offset = 0
        self.resync = set(self.last)

    def poll(self) -> None:
        if self.handle is None and not self._open():
            return
        self._read()
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return  # renamed, the new file not there yet: the old one was read to its end
        if st.st_ino != self.inode:
            self._read()  # the old file's last lines, written before the rename
            self.handle.close()
            self.handle = None
            if self._open():
                self._rewritten("log_rotated")
                self._read()
        elif st.st_size < self.offset:
            self._rewritten("log_truncated")
            self._read()

    def _read(self) -> None:
        self.handle.seek(self.offset)
        data = self.handle.read()
        end = data.rfind(b"\n") + 1  # complete lines only: a line being written waits
        for line in data[:end].decode("utf-8", "replace").splitlines():
            self._line(line)
        self.offset += end

    def _line(self, line: str) -> None:
        parts = line.split()
        if len(parts) < 4 or parts[0] not in self.names or parts[1].startswith(("***", "<")):
            return
        if len(parts) >= 6 and parts[5] == "INVALID":
            return  # not a measurement (features.readings.camonitor.valid_values)
        try:
            stamp = dt.datetime.strptime(f"{parts[1]} {parts[2]}", "%Y-%m-%d %H:%M:%S.%f")
            value = float(parts[3])
        except ValueError:
            return
        stamp = stamp.replace(tzinfo=dt.UTC)
        ns = (int(stamp.timestamp()) * 1_000_000 + stamp.microsecond) * 1000
        pv = parts[0]
        if pv in self.resync:
            if ns <= self.last[pv]:
                return  # taken from the file before it was rewritten
            self.resync.discard(pv)
        self.last[pv] = ns
        self.emit(pv, ns, value)


class CASource:
    """EPICS Channel Access (caproto's asyncio client), server at ``host:port``."""

    def __init__(self, config, emit, status):
        self.config, self.emit, self.status = config, emit, status
        self.names = sorted({n for a in config.axes for n in a.channels.values()})
        self.kinds = _kinds(config)
        self.context = self.pvs = None

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        pass

    async def start(self, timeout_s: float) -> None:
        os.environ["EPICS_CA_ADDR_LIST"] = self.config.address
        os.environ["EPICS_CA_AUTO_ADDR_LIST"] = "NO"
        from caproto.asyncio.client import Context

        self.context = Context()
        self.pvs = await self.context.get_pvs(*self.names, timeout=timeout_s)
        for pv in self.pvs:
            try:
                await pv.wait_for_connection(timeout=timeout_s)
            except TimeoutError:
                raise InputError(f"PV {pv.name} does not answer at {self.config.address} "
                                 f"within {timeout_s:g} s (no such PV, or no server)",
                                 parameter="config") from None
            reading = await pv.read(data_type="control", timeout=timeout_s)
            unit = getattr(reading.metadata, "units", b"")
            unit = unit.decode() if isinstance(unit, bytes) else str(unit)
            error = _unit_error(pv.name, unit, self.kinds[pv.name])
            if error is not None:
                raise error
        for pv in self.pvs:
            pv.subscribe(data_type="time").add_callback(self._callback)

    async def _callback(self, sub, response) -> None:
        # a coroutine: caproto awaits it on the loop in arrival order, where a plain function
        # would run in a thread pool, out of order and beside the other channels' updates
        stamp = response.metadata.stamp
        ns = ((stamp.secondsSinceEpoch + EPICS_EPOCH_S) * 1_000_000_000
              + stamp.nanoSeconds)
        self.emit(sub.pv.name, ns, float(response.data[0]))

    async def run(self) -> None:
        # caproto reconnects a lost circuit and renews the subscriptions itself; watch only
        # reports the state of the channels
        down = False
        while True:
            now_down = not all(pv.connected for pv in self.pvs)
            if now_down != down:
                self.status({"event": "source_down" if now_down else "source_up"})
                down = now_down
            await asyncio.sleep(0.2)

    async def close(self) -> None:
        if self.context is not None:
            await self.context.disconnect()


class PVASource:
    """EPICS PV Access (p4p's asyncio client), searching at ``host:port`` (the server's UDP
    search port). p4p renews a subscription itself when its server comes back; a channel is
    down from its ``Disconnected`` to its next value."""

    def __init__(self, config, emit, status):
        self.config, self.emit, self.status = config, emit, status
        self.names = sorted({n for a in config.axes for n in a.channels.values()})
        self.kinds = _kinds(config)
        self.context, self.subs = None, []
        self.down: set = set(self.names)  # channels without a value since (re)connecting
        self.first = asyncio.Event()
        self.was_down = False
        self.failed: InputError | None = None  # a refusal found in a callback

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        pass

    async def start(self, timeout_s: float) -> None:
        from p4p.client.asyncio import Context

        host, _, port = self.config.address.rpartition(":")
        conf = {"EPICS_PVA_ADDR_LIST": host or self.config.address,
                "EPICS_PVA_AUTO_ADDR_LIST": "NO"}
        if port.isdigit():
            conf["EPICS_PVA_BROADCAST_PORT"] = port
        self.context = Context("pva", conf=conf, useenv=False, nt=False)
        # a deep queue, so that a burst is delivered rather than squashed into its last value
        request = "record[queueSize=10000]field()"
        self.subs = [self.context.monitor(name, self._callback(name), request,
                                          notify_disconnect=True) for name in self.names]
        try:
            await asyncio.wait_for(self.first.wait(), timeout_s)
        except TimeoutError:
            missing = ", ".join(sorted(self.down)[:3])
            raise InputError(f"PV {missing} does not answer at {self.config.address} within "
                             f"{timeout_s:g} s (no such PV, or no server)",
                             parameter="config") from None
        if self.failed is not None:
            raise self.failed

    def _callback(self, name: str):
        async def callback(value) -> None:
            if isinstance(value, Exception):
                if name not in self.down:
                    self.down.add(name)
                    if not self.was_down:
                        self.was_down = True
                        self.status({"event": "source_down", "channel": name})
                return
            if name in self.down:
                self._check_unit(name, value)
                self.down.discard(name)
                if not self.down:
                    self.first.set()
                    if self.was_down:
                        self.was_down = False
                        self.status({"event": "source_up"})
            stamp = value["timeStamp"]
            self.emit(name, int(stamp["secondsPastEpoch"]) * 1_000_000_000
                      + int(stamp["nanoseconds"]), float(value["value"]))
        return callback

    def _check_unit(self, name: str, value) -> None:
        try:
            unit = str(value["display.units"])
        except (KeyError, TypeError):
            unit = ""  # no display metadata: the values are checked as they come
        error = _unit_error(name, unit, self.kinds[name])
        if error is not None and self.failed is None:
            self.failed = error
            self.first.set()

    async def run(self) -> None:
        while self.failed is None:
            await asyncio.sleep(0.2)
        raise self.failed

    async def close(self) -> None:
        for sub in self.subs:
            sub.close()
        if self.context is not None:
            self.context.close()


class OPCUASource:
    """OPC UA (asyncua), server at ``opc.tcp://host:port``: one subscription with a monitored
    item per channel, each sample placed by its SourceTimestamp. asyncua does not renew a
    subscription on a server that restarted, so the source does: a lost connection is
    retried with a fresh session after ``BACKOFF_S`` (the last delay repeated), until it
    answers again.

    A channel is a node id (``ns=2;s=M1.X.CmdPos``), a path of browse names from the Objects
    folder (``M1/X/CmdPos``), or a node id followed by browse names (``ns=2;s=M1.X/CmdPos``):
    an OPC 40502 CncAxisType axis gives CmdPos, PosIndirect/ActPos and PosDirect/ActPos."""

    # the server's queue per monitored item: a burst between two publishes is delivered whole
    QUEUE = 10000
    PUBLISH_MS = 50

    def __init__(self, config, emit, status):
        self.config, self.emit, self.status = config, emit, status
        self.names = sorted({n for a in config.axes for n in a.channels.values()})
        self.kinds = _kinds(config)
        self.client = None
        self.lost = asyncio.Event()

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        pass

    async def start(self, timeout_s: float) -> None:
        try:
            await asyncio.wait_for(self._connect(check=True), timeout_s)
        except (TimeoutError, OSError) as err:
            await self.close()
            raise InputError(f"the OPC UA server {self.config.address} does not answer within "
                             f"{timeout_s:g} s ({type(err).__name__})", parameter="config") from None

    async def _connect(self, check: bool = False) -> None:
        import logging

        from asyncua import Client

        # asyncua logs every lost connection with its traceback; watch says source_down
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)
        self.lost = asyncio.Event()
        client = Client(self.config.address, timeout=max(self.config.timeout_s, 1.0))
        self.client = client

        async def lost(_exc) -> None:
            self.lost.set()

        client.connection_lost_callback = lost
        await client.connect()
        nodes = {}
        for name in self.names:
            nodes[name] = node = await self._resolve(name)
            if check:
                error = _unit_error(name, await self._unit(node), self.kinds[name])
                if error is not None:
                    raise error
        subscription = await client.create_subscription(self.PUBLISH_MS, _Handler(self, nodes))
        await subscription.subscribe_data_change(list(nodes.values()), queuesize=self.QUEUE)

    async def _resolve(self, name: str):
        from asyncua import ua

        client = self.client
        head, _, rest = name.partition("/")
        if head.startswith(("ns=", "i=", "s=", "g=", "b=")):
            node, path = client.get_node(head), [p for p in rest.split("/") if p]
        else:
            node, path = client.nodes.objects, name.split("/")
        try:
            await node.read_browse_name()
            for part in path:
                children = {(await c.read_browse_name()).Name: c
                            for c in await node.get_children()}
                if part not in children:
                    raise ua.UaStatusCodeError(ua.StatusCodes.BadNodeIdUnknown)
                node = children[part]
        except (ua.UaStatusCodeError, ValueError):
            raise InputError(f"node {name} does not exist at {self.config.address}; expected a "
                             "node id or browse names (an OPC 40502 axis: CmdPos, "
                             "PosIndirect/ActPos, PosDirect/ActPos)", parameter="config") from None
        return node

    async def _unit(self, node) -> str:
        """The variable's EngineeringUnits (OPC UA Part 8 EUInformation), as a unit name."""
        for child in await node.get_properties():
            if (await child.read_browse_name()).Name == "EngineeringUnits":
                eu = await child.read_value()
                return {5066068: "mm", 17476: "deg"}.get(
                    getattr(eu, "UnitId", None), str(eu.DisplayName.Text or ""))
        return ""  # no EngineeringUnits: the values are checked as they come

    async def run(self) -> None:
        attempt = 0
        while True:
            await self.lost.wait()
            self.status({"event": "source_down", "address": self.config.address})
            while True:
                await self.close()
                await asyncio.sleep(BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
                attempt += 1
                try:
                    await asyncio.wait_for(self._connect(), self.config.timeout_s)
                except (TimeoutError, OSError, InputError):
                    continue
                except Exception as err:  # asyncua's own errors while the server starts
                    if type(err).__module__.startswith("asyncua"):
                        continue
                    raise
                attempt = 0
                self.status({"event": "source_up", "address": self.config.address})
                break

    async def close(self) -> None:
        import contextlib

        if self.client is not None:
            client, self.client = self.client, None
            with contextlib.suppress(Exception):  # a lost server cannot say goodbye
                await asyncio.wait_for(client.disconnect(), 2.0)


class _Handler:
    """asyncua's subscription handler: each notification in arrival order on the loop."""

    def __init__(self, source: OPCUASource, nodes: dict):
        self.source = source
        self.names = {node.nodeid: name for name, node in nodes.items()}

    def datachange_notification(self, node, val, data) -> None:
        import datetime as dt

        stamp = data.monitored_item.Value.SourceTimestamp
        if stamp is None or val is None:
            return  # no value (a bad status): not a sample
        if stamp.tzinfo is not None:
            stamp = stamp.astimezone(dt.UTC).replace(tzinfo=None)
        ns = (stamp - dt.datetime(1970, 1, 1)) // dt.timedelta(microseconds=1) * 1000
        self.source.emit(self.names[node.nodeid], ns, float(val))

    def status_change_notification(self, status) -> None:
        self.source.lost.set()


def _kinds(config) -> dict:
    return {n: ("rotary" if a.axis in "ABC" else "linear")
            for a in config.axes for n in a.channels.values()}


def _unit_error(name: str, unit: str, kind: str) -> InputError | None:
    """A channel whose engineering unit is not the axis's (mm, or deg on a rotary axis)."""
    if unit.strip() in UNITS[kind]:
        return None
    return InputError(f"channel {name} is in {unit!r}; expected {UNITS[kind][0]} (watch takes "
                      "positions in the axis's unit, as monitor does)", parameter="config")


SOURCES = {"log": LogSource, "ca": CASource, "pva": PVASource, "opcua": OPCUASource}
