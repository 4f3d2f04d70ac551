"""Where per-partition work runs: in this process (the default) or on a Dask cluster.

A job that scales past one machine (``monitor``) is a pure function of one partition (a
machine axis's day of traces) whose result is small; ``map_partitions`` runs it over every
partition and returns the results in order, whichever engine runs it. Each task reads its own
partition, so memory is bounded by one partition per worker, not by the dataset.

Engines:

- ``local``: in this process, a thread per core (the work is numpy, which releases the GIL);
  nothing to start.
- ``dask``: Dask (``dask.delayed``). Without an address, Dask's local threaded scheduler (its
  "local mode": no cluster, starts at once, tasks share the process); with ``address``
  (``tcp://host:8786``) an existing ``dask.distributed`` scheduler, whose workers must have this
  package installed. A scheduler that does not answer within ``SCHEDULER_TIMEOUT_S`` is
  refused: ``distributed`` bounds the TCP connection but waits for the scheduler's handshake
  without a limit, so a port that accepts and never answers (a stalled scheduler, another
  service) would hang the job.

Why Dask and not Spark: the work per partition is numpy and pandas, which Dask runs as it is,
in Python, with no JVM to start and no Arrow round trip per group (Spark's ``applyInPandas``);
it installs from PyPI as a pure-Python package, starts in milliseconds in CI, and a team's
existing Dask or Kubernetes cluster takes the same tasks unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from features.readings.errors import InputError

ENGINES = ("local", "dask")
# Seconds a Dask scheduler has to connect and answer the handshake (a scheduler on a busy
# cluster answers within a second; ten leave room for a slow network).
SCHEDULER_TIMEOUT_S = 10


def map_partitions(function: Callable, items: Sequence, *, engine: str = "local",
                   address: str | None = None, progress=None) -> list:
    """``[function(item) for item in items]`` on ``engine``, in ``items``' order.

    Parameters
    ----------
    function : callable
        A pure, module-level function (a cluster pickles it by name).
    items : sequence
        One partition each (paths to read, or small frames).
    engine : {'local', 'dask'}
        Where it runs (module docstring).
    address : str, optional
        A Dask scheduler's address; only with ``engine='dask'``.
    progress : callable, optional
        ``progress(done, total, what)`` after each partition (local engine).

    Raises
    ------
    InputError
        An unknown engine, an address without a cluster engine, a scheduler that cannot be
        reached or does not answer within ``SCHEDULER_TIMEOUT_S``.
    """
    if engine not in ENGINES:
        raise InputError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}",
                         parameter="engine")
    if engine == "local":
        if address is not None:
            raise InputError("the local engine takes no address; expected --engine dask",
                             parameter="address")
        return _local(function, items, progress)
    return _dask(function, items, address)


def _local(function: Callable, items: Sequence, progress) -> list:
    """In this process, on a thread per core: the work is numpy, which releases the GIL, so
    two partitions run at once on two cores; the results come back in ``items``' order."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    workers = min(len(items), os.cpu_count() or 1)
    if workers <= 1:
        results = map(function, items)
        return [_reported(r, i, len(items), progress) for i, r in enumerate(results)]
    with ThreadPoolExecutor(workers, thread_name_prefix="partition") as pool:
        results = pool.map(function, items)
        return [_reported(r, i, len(items), progress) for i, r in enumerate(results)]


def _reported(result, i: int, total: int, progress):
    if progress is not None:
        progress(i + 1, total, "partitions")
    return result


def _dask(function: Callable, items: Sequence, address: str | None) -> list:
    import dask

    tasks = [dask.delayed(function, pure=True)(item) for item in items]
    if address is None:
        return list(dask.compute(*tasks, scheduler="threads"))
    from distributed import Client

    _answers(address, SCHEDULER_TIMEOUT_S)
    try:
        client = Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s", set_as_default=False)
    except OSError as err:
        raise InputError(f"cannot reach the Dask scheduler at {address}: {err}",
                         parameter="address") from None
    with client:
        return list(client.gather(client.compute(tasks)))


def _answers(address: str, seconds: float) -> None:
    """Refuse a scheduler that does not connect and answer the handshake within ``seconds``
    (``distributed.Client`` would wait for the handshake forever)."""
    import asyncio

    from distributed.comm import connect

    async def handshake():
        comm = await asyncio.wait_for(connect(address, timeout=seconds), seconds)
        await comm.close()

    try:
        asyncio.run(handshake())
    except TimeoutError:  # asyncio's, since Python 3.11; before OSError, of which it is one
        raise InputError(f"Dask scheduler at {address} did not answer within {seconds:g} s",
                         parameter="address") from None
    except (OSError, ValueError) as err:
        raise InputError(f"cannot reach the Dask scheduler at {address}: {err}",
                         parameter="address") from None
