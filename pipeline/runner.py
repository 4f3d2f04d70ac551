"""The one runner: every job runs through ``run(job, **params)``, whoever asks for it (the
CLI's commands, experiment files, ``bl.<job>(...)``).

The job itself is a pure workflow function (``pipeline.workflows``); what happens around it is
done here, the same way for every entry point (kedro's runner and hooks):

1. **parameters**: bound to the workflow's signature and checked against its table
   (``PARAMETERS``; exact names: an unknown one is an error naming it, never skipped);
2. **data selection**: ``machine``, ``axis``, ``since``, ``until`` select the tests of the
   job's readings (``data`` or ``files``) in every job: the runner reads them with only the
   selected tests, or, for a job whose record says ``source=True``, hands it a ``Source``
   (``pipeline.steps.source``: the data as given, their format, the selection and a raw log's
   reader options), from which the job reads the selected tests or the whole fleet and the
   store the readings came from (a workflow that declares a filter itself applies it itself);
3. **tracking** (``track``): a tracked job (``Workflow.tracked``) logs its result's
   ``tracking_record()`` to MLflow (parameters, metrics, artifacts, a model to register and
   the champion alias) through ``pipeline.tracking.background``: from the ``backlash`` program the
   MLflow child starts while the job computes; inside an active MLflow run (an experiment
   file's) the record is logged as a nested run. A job that logs while it computes
   (``Workflow.logs_while_running``: a search whose trials are kept as each finishes) gets
   the live run its record names as its ``live`` parameter instead, which the runner ends
   with the job after logging the result's record into it;
4. **output**: ``out`` is written by ``result.write(out)`` (a workflow that takes ``out``
   itself writes it);
5. **the fleet store** (``store``): a job whose record names its recorder
   (``Workflow.records``) records its result there after writing; the store is opened first,
   so a bad store is refused before any work, and the records are checked before the result
   is written, so a result that cannot be recorded writes nothing. A job that operates on a
   store (``Workflow.store_access``: ingest, void, check, watch) gets it opened as its record
   says, before any work. A workflow never opens a store itself;
6. **progress**: ``progress(done, total, what)`` goes to workflows that report it.

Tracking default: ``TRACK = True``, for every entry point (the CLI's ``--no-track``,
``track=False`` in Python and in an experiment step's ``with``): a tracked job logs what it
did wherever it runs, so a model trained from Python is registered as one trained by the CLI.
Only tracked jobs (``Workflow.tracked``) touch MLflow; the others never import it.

A parameter whose default depends on where the job runs (a study storage in the tracking
folder) is resolved here when the call leaves it None (``Workflow.runtime_defaults``).

Everything that differs from one job to another is declared on its record
(``pipeline.workflows.Workflow``: ``tracked``, ``source``, ``records``, ``store_access``,
``model_logging``, ``logs_while_running``, ``runtime_defaults``, ``reader_options``); this
module names no job.

What the tracking gave (``run_id``; ``version`` and ``champion`` of a registered model) is
``result.tracking``; a store's record line is ``result.recorded``.
"""

from __future__ import annotations

import contextlib
import inspect
import sys

from features.readings.errors import InputError
from features.readings.selection import NAMES as SELECTION

TRACK = True  # the one default of every entry point
READINGS = ("data", "files")  # the parameter of a workflow that takes the readings
LIVE = "live"  # the parameter of a workflow that logs while it runs (its live run)
STORE = "store"  # the fleet store a job records into or operates on (``data`` is what it reads)


def run(job: str, /, *args, track: bool = TRACK, out=None, store=None, progress=None,
        **params):
    """Run job ``job`` with ``params``: the same work, tracking and records from every entry
    point.

    Parameters
    ----------
    job : str
        A job name (``pipeline.workflows.NAMES``).
    *args, **params
        The workflow's parameters, by its Python names; ``machine``, ``axis``, ``since``,
        ``until`` select the tests of its ``data``.
    track : bool
        Log a tracked job's result to MLflow (default ``TRACK``, True).
    out : str or path-like, optional
        Where the result writes its files.
    store : str, path-like or Store, optional
        Fleet store: the one a job operates on (``Workflow.store_access``), else where its
        result is recorded (``Workflow.records``).
    progress : callable, optional
        ``progress(done, total, what)``, for the workflows that report progress.

    Returns
    -------
    pipeline.results.Result
        The workflow's result, with ``tracking`` (dict, empty when not tracked) and
        ``recorded`` (the store's record, or None).
    """
    from pipeline.workflows import workflow

    record = workflow(job)
    if not isinstance(track, bool):
        raise InputError(f"must be True or False; got {track!r}", parameter="track")
    declared = inspect.signature(record.function).parameters
    extra = {"out": out, "store": store, "progress": progress}
    params.update({k: v for k, v in extra.items() if k in declared and v is not None})
    nested = _active_run()
    bound = _bound(record, declared, args, params)
    _checked(record, bound)
    bound = _defaults(record, bound)
    bound = _selected(record, declared, bound)
    opened = _opened(record, declared, store)
    bound = _operated(record, declared, bound)
    live = _live(record, track and not nested)
    if live is not None:
        bound[LIVE] = live
    with _tracking(record, track and live is None, nested) as tracking, \
            live or contextlib.nullcontext():
        result = record.function(**bound)
        if opened is not None:  # records that would be refused: nothing written or logged
            _recorder(record)(None, result)
        tracking.write_and_log(result, None if "out" in declared else out)
        if live is not None:
            tracking.logged = live.finish(result)
    result.tracking = tracking.logged
    result.recorded = None if opened is None else _recorder(record)(opened, result)
    return result


def _bound(record, declared, args: tuple, params: dict) -> dict:
    """The keyword parameters of the call, bound to the workflow's signature: an unknown
    name is an error naming it (nothing is skipped)."""
    known = set(declared) | set(SELECTION) | set(record.reader_options)
    for name in params:
        if name not in known:
            raise InputError(f"is not a parameter of {record.name}; expected one of "
                             f"{', '.join(declared)}", parameter=name)
    own = {k: v for k, v in params.items() if k in declared}
    try:
        bound = inspect.signature(record.function).bind(*args, **own)
    except TypeError as err:
        raise InputError(f"{record.name}: {err}") from None
    chosen = {k: v for k, v in params.items() if k not in declared and v is not None}
    return {**bound.arguments, **chosen}


def _checked(record, bound: dict) -> None:
    """Every parameter given, checked against the job's table (``PARAMETERS``) before any
    work: the signature bound, no name skipped (the selection is checked as it is read)."""
    from pipeline.workflows import check_params

    table = record.parameters
    check_params(table, {k: v for k, v in bound.items()
                         if k != "progress" and not (k in SELECTION and k not in table)},
                 record.name)


def _defaults(record, bound: dict) -> dict:
    """The parameters the call left None whose default depends on where the job runs
    (``Workflow.runtime_defaults``), resolved."""
    from pipeline.workflows import imported

    for name, dotted in record.runtime_defaults:
        if bound.get(name) is None:
            bound[name] = imported(dotted)()
    return bound


def _live(record, track: bool):
    """The live run of a job that logs while it computes (``Workflow.logs_while_running``),
    when it is tracked outside an experiment's run; else None (its result is logged after it,
    as any tracked job's)."""
    if not (track and record.tracked and record.logs_while_running):
        return None
    from pipeline.workflows import imported

    return imported(record.logs_while_running)(record.name)


def _selected(record, declared, params: dict) -> dict:
    """``machine``, ``axis``, ``since``, ``until`` not taken by the workflow itself: its
    ``data`` read with only the selected tests (``pipeline.steps.source.readings_of``), or, for
    a job that takes a Source (``Workflow.source``), the Source of its data."""
    chosen = {k: params.pop(k) for k in SELECTION if k in params and k not in declared}
    # a raw log's reader options the workflow's table declares but its function does not take
    options = record.reader_options
    raw = {k: params.pop(k) for k in options if k in params and k not in declared}
    raw = {k: v for k, v in raw.items() if v is not None}
    if record.source:
        return _with_source(params, chosen, raw)
    if not chosen and not raw:
        return params
    name = next((n for n in READINGS if n in declared), None)
    if name is None or params.get(name) is None:
        raise InputError(f"selects tests of readings; {record.name} reads none",
                         parameter=next(iter(chosen or raw)))
    data, fmt = params[name], params.get("format", "auto")
    # the reader takes the options (those of a function that takes them too): the workflow
    # gets the frame
    raw |= {k: params.pop(k) for k in options if params.get(k) is not None}
    if isinstance(data, (list, tuple)):
        params[name] = [_select(one, fmt, chosen, raw) for one in data]
    else:
        params[name] = _select(data, fmt, chosen, raw)
    return params


def _with_source(params: dict, chosen: dict, raw: dict) -> dict:
    """The job's ``data`` as a Source: as given, with its format, selection and reader
    options; the job reads what it needs from it."""
    from features.readings.selection import selection
    from pipeline.steps.source import Source

    params["data"] = Source(params["data"], params.get("format", "auto"),
                            selection(**chosen), raw)
    return params


def _select(data, format: str, chosen: dict, raw: dict):
    import os

    from features.readings.selection import selection
    from pipeline.steps.source import readings_of

    if isinstance(data, (str, os.PathLike)):
        from pipeline.store import is_store

        if os.path.isdir(data) and not is_store(data):  # a model directory, not readings
            raise InputError(f"selects tests of readings; {data} is a folder, not a fleet "
                             "store", parameter=next(iter(chosen)))
        return readings_of(data, format, selection=selection(**chosen), options=raw)
    return readings_of(data, selection=selection(**chosen))


def _opened(record, declared, store):
    """The store a result is recorded in, opened before any work (a bad store is refused
    first); None when nothing is recorded by the runner."""
    if store is None or STORE in declared:
        return None
    if record.records is None:
        raise InputError(f"{record.name} records nothing in a fleet store", parameter=STORE)
    from pipeline.store.records import open_for_records

    return open_for_records(store)


def _recorder(record):
    """``function(store, result)`` that records the job's result (``Workflow.records``)."""
    from pipeline.workflows import imported

    return imported(record.records)


def _operated(record, declared, bound: dict) -> dict:
    """The fleet store a job operates on (its ``store``), opened as its record says
    (``Workflow.store_access``) before any work: the workflow gets the ``Store``."""
    access = record.store_access
    if access is None:
        return bound
    from pipeline.store import open_store
    from pipeline.store.base import Store

    location = bound.get(STORE)
    if access == "record" and location is not None:  # a Store given is checked too
        from pipeline.store.records import open_for_records

        bound[STORE] = open_for_records(location)
        return bound
    if location is None or isinstance(location, Store):
        return bound
    if access.startswith("write if "):
        flag = access.removeprefix("write if ")
        write = bool(bound.get(flag, declared[flag].default))
    elif access in ("read", "write"):
        write = access == "write"
    else:
        raise ValueError(f"{record.name}: store_access {access!r} is not read, write, record "
                         "or 'write if NAME'")
    bound[STORE] = open_store(location, write=write, parameter=STORE)
    return bound


class _Untracked:
    """The tracking hook of a job that logs nothing: it only writes ``out``."""

    def __enter__(self):
        self.logged = {}
        return self

    def __exit__(self, *exc_info):
        return None

    def write_and_log(self, result, out) -> None:
        if out is not None:
            result.files = dict(result.write(out) or result.files)


class _Tracked(_Untracked):
    """Logs a result's ``tracking_record()`` into one MLflow run: in a background child from
    the ``backlash`` program (forked as the job begins, so importing mlflow overlaps the
    work), nested under an active run (an experiment's), else in this process."""

    def __init__(self, record, nested: bool):
        self.record, self.nested = record, nested

    def __enter__(self):
        import pandas  # noqa: F401 - imported once, before the MLflow child is forked: both use it

        from pipeline.tracking import runs as tracking
        from pipeline.tracking.background import BackgroundRun

        self.logged, self._tracking, self._run = {}, tracking, None
        tracking.check_uri()
        if not self.nested:
            from pipeline.workflows import imported

            prepare = self.record.model_logging
            self._run = BackgroundRun(self.record.name, tracking.log_into,
                                      None if prepare is None else imported(prepare))
        return self

    def __exit__(self, *exc_info):
        if self._run is not None:
            self._run.close(*exc_info)

    def write_and_log(self, result, out) -> None:
        tracking = self._tracking
        if self._run is None:  # inside an experiment's run
            super().write_and_log(result, out)
            self.logged = tracking.log_result(result, nested=True)
            return
        if out is not None and hasattr(result, "draw"):
            return self._drawn_beside(result, out)
        super().write_and_log(result, out)
        record = result.tracking_record()
        if record is None:
            return
        self._run.start(record.run_name)  # the input is valid: the run may start
        self._run.log(tracking.record_data(record))
        self.logged = self._run.finish()

    def _drawn_beside(self, result, out) -> None:
        """A result that saves and draws (a trained model's): a second child draws the figures while
        the MLflow child logs the model (the record reads what the job computed)."""
        from pipeline.tracking.background import BackgroundTask

        tracking = self._tracking
        result.save(out)
        with BackgroundTask(lambda: [str(p) for p in result.draw()]) as drawing:
            record = result.tracking_record()
            self._run.start(record.run_name)
            self._run.log(tracking.record_data(record))
            result.drawn(drawing.result())
        self._run.log(tracking.record_data(result.figures_record()))
        self.logged = self._run.finish()


def _tracking(record, track: bool, nested: bool):
    return _Tracked(record, nested) if track and record.tracked else _Untracked()


def _active_run() -> bool:
    """An MLflow run is open in this process (an experiment file's): log nested in it."""
    mlflow = sys.modules.get("mlflow")
    return mlflow is not None and mlflow.active_run() is not None
