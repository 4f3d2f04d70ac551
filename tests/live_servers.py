"""Controller servers for the watch tests, on 127.0.0.1 only: an EPICS Channel Access IOC
(caproto), a PV Access server (p4p) and an OPC UA server with OPC 40502 CncAxisType-style axis
nodes (asyncua), each playing a recorded trace with the trace's own timestamps.

Run as ``python -m tests.live_servers PROTOCOL TRACE.npz --port P [--start I] [--stop J]``:
the server takes sample ``start`` as its channels' initial values, says ``ready``, waits for
``go`` on stdin (the test says it once the watcher has every channel's first value, so that
what the server plays is what the watcher receives; the CA IOC also waits for a subscriber on
every channel), then plays samples ``start+1 .. stop-1`` as fast as its client takes them, and keeps
serving until it is killed or ``--linger`` seconds pass. On stdout: ``ready``, then
``played N`` (the index after the last sample played) when done.

TRACE.npz holds ``names`` (channel names, one per column), ``ns`` (int64 sample times, ns since
the epoch, UTC) and ``values`` (samples x channels); ``units`` optionally (one per channel: mm, deg or counts).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys

import numpy as np

EPICS_EPOCH_S = 631_152_000
# Samples played between yields to the server's send loop: small enough that no subscription
# queue overflows (an overflowing queue drops updates, and a test must know what was sent).
BURST = 20


def _say(text: str) -> None:
    print(text, flush=True)


def _load(path: str):
    with np.load(path, allow_pickle=False) as data:
        names = [str(n) for n in data["names"]]
        units = [str(u) for u in data["units"]] if "units" in data else ["mm"] * len(names)
        return names, data["ns"].astype(np.int64), data["values"].astype(float), units


# ---------------------------------------------------------------- Channel Access (caproto)
async def _ca(args) -> None:
    os.environ.update({"EPICS_CA_SERVER_PORT": str(args.port),
                       "EPICS_CAS_INTF_ADDR_LIST": "127.0.0.1",
                       "EPICS_CAS_AUTO_BEACON_ADDR_LIST": "NO",
                       "EPICS_CAS_BEACON_ADDR_LIST": "127.0.0.1",
                       "EPICS_CAS_BEACON_PORT": str(args.port + 1),
                       "EPICS_CA_REPEATER_PORT": str(args.port + 1)})
    from caproto import ChannelDouble
    from caproto.asyncio.server import Context

    names, ns, values, units = _load(args.trace)

    def stamp(i: int):
        sec, nano = divmod(int(ns[i]), 1_000_000_000)
        return (sec - EPICS_EPOCH_S, nano)

    pvdb = {name: ChannelDouble(value=float(values[args.start, j]), units=units[j],
                                timestamp=stamp(args.start), precision=6)
            for j, name in enumerate(names)}
    channels = list(pvdb.values())

    async def play(_async_lib):
        await _go()
        while not all(c._queues for c in channels):  # every channel subscribed
            await asyncio.sleep(0.02)
        for i in range(args.start + 1, min(args.stop, len(ns))):
            for j, channel in enumerate(channels):
                await channel.write(float(values[i, j]), timestamp=stamp(i))
            if i % BURST == 0:
                await asyncio.sleep(0)
                # a slow client would have caproto drop "old news": wait for the sends
                while any(c.subscription_queue.qsize() > 2 * BURST * len(channels)
                          for c in server.circuits):
                    await asyncio.sleep(0.002)
        _say(f"played {min(args.stop, len(ns))}")

    server = Context(pvdb, ["127.0.0.1"])
    await server.run(startup_hook=play)


# ---------------------------------------------------------------- PV Access (p4p)
async def _pva(args) -> None:
    from p4p.nt import NTScalar
    from p4p.server import Server
    from p4p.server.thread import SharedPV

    names, ns, values, units = _load(args.trace)
    nt = NTScalar("d", display=True)

    def value(i: int, j: int):
        sec, nano = divmod(int(ns[i]), 1_000_000_000)
        return nt.wrap({"value": float(values[i, j]), "display": {"units": units[j]},
                        "timeStamp": {"secondsPastEpoch": sec, "nanoseconds": nano}})

    pvs = {name: SharedPV(nt=nt, initial=value(args.start, j)) for j, name in enumerate(names)}
    conf = {"EPICS_PVAS_INTF_ADDR_LIST": "127.0.0.1", "EPICS_PVAS_BEACON_ADDR_LIST": "127.0.0.1",
            "EPICS_PVAS_AUTO_BEACON_ADDR_LIST": "NO", "EPICS_PVAS_SERVER_PORT": str(args.port),
            "EPICS_PVAS_BROADCAST_PORT": str(args.port)}
    with Server(providers=[pvs], conf=conf, useenv=False):
        await _go()
        for i in range(args.start + 1, min(args.stop, len(ns))):
            for j, name in enumerate(names):
                pvs[name].post(value(i, j))
            if i % BURST == 0:
                await asyncio.sleep(0.001)
        _say(f"played {min(args.stop, len(ns))}")
        await asyncio.Event().wait()


# ---------------------------------------------------------------- OPC UA (asyncua)
# EUInformation of UNECE units (OPC UA Part 8): millimetre, degree, and a count of pulses
EU = {"mm": (5066068, "mm", "millimetre"), "deg": (17476, "°", "degree"),
      "counts": (4337492, "counts", "count")}
UNITS_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


async def _opcua(args) -> None:
    import datetime as dt
    import logging

    from asyncua import Server, ua

    logging.getLogger("asyncua").setLevel(logging.ERROR)
    names, ns, values, units = _load(args.trace)
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{args.port}/")
    idx = await server.register_namespace("urn:backlash:test-cnc")

    def stamp(i: int):
        return dt.datetime(1970, 1, 1) + dt.timedelta(microseconds=int(ns[i]) // 1000)

    def value(i: int, j: int):
        return ua.DataValue(ua.Variant(float(values[i, j]), ua.VariantType.Double),
                            SourceTimestamp=stamp(i), ServerTimestamp=stamp(i))

    # names are browse paths M1/X/CmdPos, M1/X/PosIndirect/ActPos, M1/X/PosDirect/ActPos: an
    # object per machine, a CncAxisType-style object per axis, the position variables under it
    made, nodes = {}, []
    for j, name in enumerate(names):
        parent = server.nodes.objects
        parts = name.split("/")
        for k, part in enumerate(parts[:-1]):
            key = "/".join(parts[:k + 1])
            if key not in made:
                made[key] = await parent.add_object(ua.NodeId(key, idx), f"{idx}:{part}")
            parent = made[key]
        node = await parent.add_variable(ua.NodeId(name, idx), f"{idx}:{parts[-1]}", 0.0)
        unit_id, shown, text = EU[units[j]]
        await node.add_property(ua.NodeId(f"{name}/EngineeringUnits", idx),
                                ua.QualifiedName("EngineeringUnits", 0),
                                ua.EUInformation(NamespaceUri=UNITS_URI, UnitId=unit_id,
                                                 DisplayName=ua.LocalizedText(shown),
                                                 Description=ua.LocalizedText(text)))
        await node.write_value(value(args.start, j))
        nodes.append(node)
    async with server:
        await _go()
        for i in range(args.start + 1, min(args.stop, len(ns))):
            for j, node in enumerate(nodes):
                await server.write_attribute_value(node.nodeid, value(i, j))
            if i % BURST == 0:
                await asyncio.sleep(0.001)
        _say(f"played {min(args.stop, len(ns))}")
        await asyncio.Event().wait()


async def _go() -> None:
    """Say ``ready`` and wait for ``go`` on stdin: the test says it once the watcher has every
    channel's first value (these protocols tell a server of no subscription)."""
    _say("ready")
    loop = asyncio.get_running_loop()
    while True:
        line = await loop.run_in_executor(None, sys.stdin.readline)
        if line.strip() == "go" or not line:  # "go", or no test to say it
            return


PROTOCOLS = {"ca": _ca, "pva": _pva, "opcua": _opcua}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("protocol", choices=sorted(PROTOCOLS))
    parser.add_argument("trace")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--stop", type=int, default=sys.maxsize)
    parser.add_argument("--linger", type=float, default=300.0)
    args = parser.parse_args(argv)

    async def bounded():
        # a test server never outlives its test by long, whatever happens to the test
        try:
            await asyncio.wait_for(PROTOCOLS[args.protocol](args), args.linger)
        except TimeoutError:
            pass

    asyncio.run(bounded())


if __name__ == "__main__":
    main()
