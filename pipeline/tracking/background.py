"""An MLflow run whose slow start overlaps the command's own work, and other work done beside
the command's (``BackgroundTask``).

Importing mlflow and opening its store take about three seconds, longer than reading and
fitting a typical campaign. ``BackgroundRun`` hands that to a forked child process as the
command begins; the command computes meanwhile and sends the child what to log as soon as
each part is ready. Where the process cannot fork safely (no ``os.fork``, mlflow already
imported, more than one thread, or a caller other than the ``backlash`` program itself), the
same calls run in-process, in the same order, so both ways log the same run.

Protocol, one JSON line per message on a private pipe (never pickle):

1. the child imports mlflow and the store's modules, touching nothing on disk, and runs the
   optional ``prepare()`` (work the logging would otherwise do on first use);
2. ``start(run_name)``: the input is valid, so the child opens the store and starts the run;
3. ``log(record)``, any number of times: the child logs ``record`` with the given function;
4. ``finish()``: the child ends the run and answers with the merged results of the log
   calls plus ``run_id``, or with the first error it met.

A command that fails before ``start`` leaves no trace in the store; one that fails after it
leaves a run marked FAILED, as an in-process run would. A child whose parent died sees the
pipe close and stops the same way.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Self

from features.readings.errors import InputError
from pipeline.tracking import fork_allowed


def _can_fork(mlflow_free: bool = True) -> bool:
    return (fork_allowed() and hasattr(os, "fork") and threading.active_count() == 1
            and not (mlflow_free and "mlflow" in sys.modules))


class _Aborted(Exception):
    """The command stopped before it finished the run."""


class BackgroundRun:
    """``with BackgroundRun(experiment, log) as run``: ``run.start(name)``, ``run.log(record)``
    (``log(record) -> dict`` is called inside the MLflow run), ``result = run.finish()``.
    ``prepare()``, if given, runs in the child before it waits for the run: what the logging
    needs on first use is ready by then (in-process, the logging does it when it comes).

    Create it after importing what both processes use (pandas, which mlflow imports too) and
    before what only the command uses: the child is forked at once and shares the former.
    """

    def __init__(self, experiment: str, log: Callable[[dict], dict],
                 prepare: Callable[[], None] | None = None):
        self._experiment, self._log, self._prepare = experiment, log, prepare
        self._pid = self._pipes = None
        self._started = False
        self._inline = None  # the in-process run: its context stack and merged results
        if _can_fork():
            self._fork()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close(*exc_info)

    def start(self, run_name: str) -> None:
        """The input is valid: the store may be opened and the run started."""
        self._started = True
        if self._pid is not None:
            return self._send({"run_name": run_name})
        from pipeline.tracking import runs as tracking

        stack = contextlib.ExitStack()
        active = stack.enter_context(tracking.run(self._experiment, run_name))
        self._inline = (stack, {"run_id": active.info.run_id})

    def log(self, record: dict) -> None:
        """Log ``record`` in the run (in the background: without waiting for it)."""
        if self._pid is not None:
            return self._send({"record": record})
        self._inline[1].update(self._log(record))

    def finish(self) -> dict:
        """End the run; returns the merged results of the ``log`` calls and ``run_id``."""
        if self._pid is None:
            stack, result = self._inline
            self._inline = None
            stack.close()
            return result
        self._send({"finish": True})
        reply = self._receive()
        self.close()
        return _checked(reply, "MLflow logging")

    def close(self, exc_type=None, exc=None, tb=None) -> None:
        """End what is open: a run left by an exception ends FAILED (a child sees its pipe
        close), a child that has not started is stopped, and no child is left behind."""
        if self._inline is not None:
            stack, self._inline = self._inline[0], None
            stack.__exit__(exc_type, exc, tb)
        if self._pipes is not None:
            for pipe in self._pipes:
                pipe.close()
            self._pipes = None
        if self._pid is not None and not self._started:
            os.kill(self._pid, signal.SIGKILL)  # it has only imported: nothing to clean up
        if self._pid is not None and (exc_type is None or not self._started):
            os.waitpid(self._pid, 0)  # do not leave a zombie behind
        self._pid = None

    def _fork(self) -> None:
        down_r, down_w = os.pipe()
        up_r, up_w = os.pipe()
        pid = _fork_flushed()
        if pid == 0:
            os.close(down_w)
            os.close(up_r)
            _child(os.fdopen(down_r, "r"), os.fdopen(up_w, "w"), self._experiment, self._log,
                   self._prepare)
        os.close(down_r)
        os.close(up_w)
        self._pid = pid
        self._pipes = (os.fdopen(down_w, "w"), os.fdopen(up_r, "r"))

    def _send(self, message: dict) -> None:
        try:
            self._pipes[0].write(json.dumps(message) + "\n")
            self._pipes[0].flush()
        except BrokenPipeError:
            pass  # the child stopped on an error; ``finish`` reads it

    def _receive(self) -> dict | None:
        line = self._pipes[1].readline()
        return json.loads(line) if line else None


class BackgroundTask:
    """``with BackgroundTask(work) as task``: ``work()`` runs in a forked child while the
    caller goes on, and ``task.result()`` waits for what it returned (plain JSON data).

    The child is a copy of the caller at the fork, so it needs nothing sent; whatever else it
    changes stays its own. Where the process may not fork (as ``BackgroundRun``, except that
    mlflow may be imported), ``work`` runs in-process when ``result()`` is called. Leaving the
    ``with`` block on an exception stops a child still at work: a failed command leaves
    nothing behind that its clean-up would miss.
    """

    def __init__(self, work: Callable[[], object]):
        self._work, self._pid, self._inbox = work, None, None
        if _can_fork(mlflow_free=False):
            self._fork()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, *_) -> None:
        if self._pid is not None:
            if exc_type is not None:
                os.kill(self._pid, signal.SIGKILL)
            self._inbox.close()
            os.waitpid(self._pid, 0)
            self._pid = None

    def result(self):
        """What ``work()`` returned; its error (an ``InputError`` as such) if it failed."""
        if self._pid is None:
            return self._work()
        line = self._inbox.readline()
        self.__exit__(None)
        return _checked(json.loads(line) if line else None, "background task")["value"]

    def _fork(self) -> None:
        up_r, up_w = os.pipe()
        pid = _fork_flushed()
        if pid == 0:
            os.close(up_r)
            _answer(os.fdopen(up_w, "w"), self._work)
        os.close(up_w)
        self._pid, self._inbox = pid, os.fdopen(up_r, "r")


def _fork_flushed() -> int:
    """``os.fork()`` after flushing stdout and stderr, or the child would print the parent's
    buffered text again."""
    sys.stdout.flush()
    sys.stderr.flush()
    return os.fork()


def _checked(reply: dict | None, what: str) -> dict:
    """A child's reply, or its error raised here (an ``InputError`` as such)."""
    if reply is None:
        raise RuntimeError(f"{what} ended without an answer")
    if "error" in reply:
        if reply.get("input"):
            raise InputError(reply["error"])
        raise RuntimeError(f"{what} failed:\n{reply['error']}")
    return reply


def _answer(outbox, work) -> None:
    """Body of a task's child: ``work()``'s value or error on ``outbox``; never returns."""
    gc.disable()  # short-lived: its garbage goes back with the process
    _reply_and_exit(outbox, lambda: {"value": work()})


def _child(inbox, outbox, experiment: str, log, prepare) -> None:
    """Body of the forked child; never returns (``os._exit``), so the parent's ``finally``
    blocks, atexit handlers and buffered files are never run twice."""
    # Short-lived and ended by os._exit: cyclic garbage goes back with the process, and no
    # collector passes over the growing heap while mlflow imports (15 % of the import time).
    gc.disable()
    _reply_and_exit(outbox, lambda: _serve(inbox, experiment, log, prepare))


def _reply_and_exit(outbox, body) -> None:
    """Run a child's ``body``, write its reply (or its error) as one JSON line on ``outbox``
    and end the process with ``os._exit``: 1 after a bug, else 0. An aborted run (the parent
    went away) writes nothing."""
    code = 0
    try:
        reply = body()
    except _Aborted:
        reply = None
    except InputError as err:
        reply = {"error": err.line(), "input": True}
    except BaseException:  # noqa: BLE001 - a bug: the parent raises it with this traceback
        reply, code = {"error": traceback.format_exc()}, 1
    try:
        if reply is not None:
            outbox.write(json.dumps(reply) + "\n")
            outbox.flush()
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


def _serve(inbox, experiment: str, log, prepare) -> dict:
    from pipeline.tracking import runs as tracking

    tracking.import_store()
    if prepare is not None:
        prepare()
    start = _next(inbox)
    with tracking.run(experiment, start["run_name"]) as active:
        result = {"run_id": active.info.run_id}
        while "finish" not in (message := _next(inbox)):
            result.update(log(message["record"]))
    return result


def _next(inbox) -> dict:
    """The next message; ``_Aborted`` when the parent closed the pipe (it failed or died),
    which ends a started run as FAILED."""
    line = inbox.readline()
    if not line:
        raise _Aborted
    return json.loads(line)
