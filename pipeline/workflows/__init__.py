"""Workflows: one function per job, typed keyword parameters in, a result object out.

The CLI (``pipeline.commands``), experiment files (``pipeline.experiment``) and Python users
(``pipeline.api``) all call these functions through the runner, which checks every call
against the job's ``PARAMETERS`` with ``check_params`` (scikit-learn's constraint language and
its checking, the same as the estimators' ``_parameter_constraints``:
``pipeline.steps.constraints``); a plain function of a job module that Python users call
directly (``bl.read``, ``bl.backtest``) declares its check with ``checked``, as scikit-learn's
``validate_params`` does. A workflow never prints (notes are ``BacklashWarning`` or result
fields, progress goes to the ``progress`` callback) and names Python parameters in its errors.
"""

from __future__ import annotations

from collections.abc import Mapping

from features.readings.errors import InputError


def check_params(constraints: Mapping, values: dict, caller: str) -> None:
    """Check keyword values against scikit-learn parameter constraints, with scikit-learn's
    ``validate_parameter_constraints``.

    Parameters
    ----------
    constraints : Mapping
        Parameter name -> list of constraints (``Interval``, ``StrOptions``, types,
        ``"array-like"``, ``None``...), as in scikit-learn's ``_parameter_constraints``, or its
        ``Param`` (``pipeline.steps.parameters``: its ``accepts``); a constraint may be a
        declaration of ``pipeline.steps.constraints`` (converted to scikit-learn's object
        when its parameter is first checked, once per table) and a type may be named by its
        dotted path (``"pandas.DataFrame"``, imported then).
    values : dict
        Parameter name -> value given.
    caller : str
        The workflow's name.

    Raises
    ------
    InputError
        Naming the first parameter that breaks its constraints ("must be A, B or C; got X",
        each constraint as scikit-learn words it), or that has none (no name is skipped);
        ``.parameter`` is its name. True or False where a parameter takes no boolean is refused
        (Python's ``True`` is also the int 1).
    """
    from sklearn.utils._param_validation import (
        InvalidParameterError,
        validate_parameter_constraints,
    )

    for name, value in values.items():
        if name not in constraints:  # never skipped: a parameter without a constraint
            raise InputError(f"is not a parameter of {caller}; expected one of "
                             f"{', '.join(constraints)}", parameter=name)
        given, booleans, listed = _converted(constraints, name)
        # scikit-learn lets True pass an Interval(Integral, ...) or an int type: bool is a
        # subclass of int (an Integral), so a flag written where a number belongs
        # (seed = true) would run as 1
        refused = isinstance(value, bool) and not booleans
        if not refused:
            try:
                validate_parameter_constraints({name: given}, {name: value}, caller)
            except InvalidParameterError:
                refused = True
        if refused:
            raise InputError(f"must be {listed}; got {value!r}", parameter=name)


def checked(table: Mapping, *names: str):
    """Decorator: each call of a plain function (not a job the runner calls) is checked
    against ``table`` (its job's ``PARAMETERS``) with ``check_params`` before it runs, for its
    parameters ``names``, as scikit-learn's ``validate_params`` checks a function's
    arguments."""
    import functools
    import inspect

    def decorate(function):
        signature = inspect.signature(function)

        @functools.wraps(function)
        def call(*args, **kwargs):
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            given = {n: v for n, v in bound.arguments.items() if n in names}
            check_params(table, given, function.__name__)
            return function(*args, **kwargs)

        return call

    return decorate


# id(table) -> (table, {name: (declared, scikit-learn's constraints, takes a bool, words)}):
# a table's declarations are converted once (the tables are the job modules' constants; a
# few more, made on the fly, are kept too, the oldest let go)
_CONVERTED: dict[int, tuple[Mapping, dict]] = {}
_KEPT = 64


def _converted(table: Mapping, name: str) -> tuple[list, bool, str]:
    """Parameter ``name``'s constraints in ``table`` as scikit-learn's objects, whether it
    takes a boolean, and the constraints in scikit-learn's words (``_listed``)."""
    from pipeline.steps.constraints import resolved, takes_bool

    kept = _CONVERTED.get(id(table))
    if kept is None or kept[0] is not table:
        if len(_CONVERTED) >= _KEPT:
            _CONVERTED.pop(next(iter(_CONVERTED), None), None)
        kept = _CONVERTED[id(table)] = (table, {})
    declared = getattr(table[name], "accepts", table[name])  # a Param's, or the list itself
    entry = kept[1].get(name)
    if entry is None or entry[0] is not declared:  # a name's constraints replaced: again
        given = resolved(declared)
        entry = kept[1][name] = (declared, given, takes_bool(given), _listed(given))
    return entry[1:]


def _listed(given: list) -> str:
    """The constraints ``given`` in scikit-learn's words ("A, B or C"): each constraint
    object's own ``str()``, as scikit-learn lists them in its message (hidden ones left out)."""
    from sklearn.utils._param_validation import make_constraint

    shown = [str(c) for c in map(make_constraint, given) if not c.hidden]
    return shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} or {shown[-1]}"


# --------------------------------------------------------------------------- the registry
import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Workflow:
    """One job's record: the CLI command, the experiment runner and the docs read it. The
    records are plain data (``WORKFLOWS``), so ``backlash --help`` lists every job without
    importing one; a job's module loads when its function or table is asked for.

    Attributes
    ----------
    name : str
        The job's name, also its CLI command and an experiment step's ``job``; its module is
        ``pipeline.workflows.<name with _ for ->``.
    summary : str
        One sentence: the command's help and the docs' table of jobs.
    inputs : tuple of str
        Parameters that name files or folders to read (an experiment resolves them against
        its own folder and checks they exist).
    tracked : bool
        The result is logged to MLflow (``tracking_record``) when the runner tracks
        (``pipeline.runner``).
    function_name : str or None
        The workflow function's name in its module, when not the module's own name.
    module_name : str or None
        The job's module, when not ``pipeline.workflows.<name>`` (a job added by ``register``
        from a package of its own).
    source : bool
        The job takes a ``pipeline.steps.source.Source`` for its readings (``data``): the data
        as given with the test selection, rather than a frame the runner read with only the
        selected tests. A job whose answer about an axis depends on the other axes or on the
        store the readings came from (its records, its voids) says so here.
    records : str or None
        The dotted name of ``function(store, result) -> Recorded`` that records the job's
        result in the fleet store given as ``store`` (``pipeline.store.records``): the runner
        opens the store before any work, has the records checked before the result is written
        (``function(None, result)``) and records them after; None: the job records nothing
        there. The job's table declares ``store`` for the command line, its function does not
        take it.
    store_access : str or None
        How the runner opens the fleet store a job operates on, named by its ``store``
        parameter, before any work, to hand the workflow the opened ``Store`` (a workflow never
        opens one; a ``Store`` given is handed on as it is): ``"read"``; ``"write"`` (this
        user may write; a new or empty folder opens as a store not made yet, ``exists()``
        False, which the job makes or refuses); ``"record"`` (for writing, refused when it
        holds no store yet, as ``records`` opens it); ``"write if NAME"`` (for writing when the
        job's boolean parameter ``NAME`` is true, else for reading). None: the job operates on
        no store (one it reads as ``data`` the runner reads for it).
    model_logging : str or None
        The dotted name of the function the MLflow child runs before the result is ready, to
        prepare logging a model (the imports it needs, while the job computes).
    logs_while_running : str or None
        The dotted name of ``hook(job) -> live run`` for a job that logs while it computes (a
        search whose steps are kept as each finishes, so a killed job keeps them): when the
        runner tracks outside an experiment's run, it enters the hook's object around the job
        (the run ends FINISHED, or FAILED on an error) and passes it as the job's ``live``
        parameter; the job calls ``live.start(record, killed=tags)`` once its run's record is
        known (the runs of killed jobs whose ``tag`` parameter is in ``tags`` ended as KILLED
        first; returns notes) and hands ``live.child`` (``child(record)``, picklable, from any
        process) each step's record; the runner then logs the result's ``tracking_record``
        into it (``live.finish(result)``; the children were logged already). Otherwise the job
        gets no ``live`` and its result is logged after it, as any tracked job's.
    runtime_defaults : tuple of (str, str)
        Parameters whose default depends on where the job runs: (name, dotted name of a
        function of no arguments giving it), resolved by the runner when a call leaves the
        parameter None (the workflow function itself takes it as given).
    reader_options : tuple of str
        A raw log's reader options (``pipeline.steps.parameters.RAW_LOG``) the job's table
        declares: the runner hands those its function does not take to the reader.
    """

    name: str
    summary: str
    inputs: tuple[str, ...] = ()
    tracked: bool = False
    function_name: str | None = None
    module_name: str | None = None
    source: bool = False
    records: str | None = None
    store_access: str | None = None
    model_logging: str | None = None
    reader_options: tuple[str, ...] = ()
    logs_while_running: str | None = None
    runtime_defaults: tuple[tuple[str, str], ...] = ()

    @property
    def module(self):
        return importlib.import_module(
            self.module_name or f"pipeline.workflows.{self.name.replace('-', '_')}")

    @property
    def function(self):
        """``function(**parameters, progress=None) -> Result``."""
        return getattr(self.module, self.function_name or self.name.replace("-", "_"))

    @property
    def parameters(self) -> Mapping:
        """The job's parameter table (``PARAMETERS`` of its module:
        ``pipeline.steps.parameters``): the runner checks calls against it, the CLI
        generates its options from it."""
        return self.module.PARAMETERS


def imported(dotted: str):
    """The object a record names by its dotted path (``package.module.name``): the records
    stay plain data, the module loads when the object is asked for."""
    module, _, name = dotted.rpartition(".")
    return getattr(importlib.import_module(module), name)


# A raw ISO 230-2 log's reader options (``pipeline.steps.parameters.RAW_LOG``'s names).
RAW_LOG_OPTIONS = ("channels", "reference_scale", "unit")

# Every job, in the order the CLI lists it: adding a job is a line here, its module
# (``PARAMETERS`` and the function), its command module and its docs page.
WORKFLOWS = (
    Workflow('convert',
             'Read a readings file (any input format: --format lists them) or a fleet store, '
             'validate it, write CSV/Parquet.',
             inputs=('data',), reader_options=RAW_LOG_OPTIONS),
    Workflow('ingest',
             'Validate readings files (any accepted layout) and add their tests to a fleet store (a '
             'folder, or PostgreSQL for a team); the same test twice changes nothing.',
             inputs=('files',), store_access='write'),
    Workflow('store',
             "Check a fleet store: every recorded test's readings present and intact, every part "
             "recorded, nothing orphaned (--repair mends what is provably safe).",
             function_name='check_store', store_access='write if repair'),
    Workflow('void',
             'Retire tests of a fleet store from every reader, kept with when, who and why in its '
             'audit table (--undo restores them).',
             store_access='write'),
    Workflow('iso',
             'ISO 230-2 analysis: per-target and axis figures (A, E, M, R, B) of every test.',
             inputs=('data', 'uncertainty'), reader_options=RAW_LOG_OPTIONS),
    Workflow('targets',
             'Backlash per point (pendulum minus linear or the ISO reversal value) with its '
             'uncertainty; with --uncertainty also its expanded uncertainty from a budget.',
             inputs=('data', 'uncertainty')),
    Workflow('report',
             'Printable test report (HTML and PDF): conditions, per-target table, axis figures and '
             'chart of every test, one page each.',
             inputs=('data', 'uncertainty'), reader_options=RAW_LOG_OPTIONS),
    Workflow('simulate',
             'Simulate ISO 230-2 test campaigns on the feed-drive twin; write readings and truth.',
             inputs=('config',)),
    Workflow('train',
             'Train a backlash predictor on paired tests and save it (default: the recommended '
             'model).',
             inputs=('data', 'truth', 'uncertainty'), tracked=True,
             model_logging='pipeline.tracking.runs.prepare_model_logging'),
    Workflow('predict',
             'Predict backlash with a trained model directory from new tests or from a plan table '
             '(targets and conditions); write a CSV.',
             inputs=('model', 'data', 'plan'), records='pipeline.store.records.record_forecast'),
    Workflow('compare',
             'Train every predictor (network, physics baselines, comparators) on one split; compare.',
             inputs=('data', 'truth'), tracked=True),
    Workflow('tune',
             'Tune the network (hidden sizes, activation, trainer, regularisation) by cross-'
             'validation with Optuna.',
             inputs=('data',), tracked=True,
             logs_while_running='pipeline.tracking.runs.LiveRun',
             runtime_defaults=(('storage', 'pipeline.tracking.runs.study_storage'),)),
    Workflow('rank',
             "Which inputs drive backlash given the others (driver with its effect in um, proxy, "
             "none), beside the paper's association views (weighted k-NN, ANOVA -ln(p), permutation "
             "importance, mutual information); writes an HTML report.",
             inputs=('data', 'model'), tracked=True),
    Workflow('replicate',
             "Replicate the backlash paper's results (best epoch, regression R, ANOVA Table 5, k-NN "
             "accuracy) on paired tests, with and without the deviation inputs.",
             inputs=('data', 'truth')),
    Workflow('drift',
             'Follow backlash across maintenance visits: robust trend, change points, the date it '
             'crosses a threshold, and (with --model) residual and input drift of a trained model. '
             'Exit 3 when an alert fires.',
             inputs=('data', 'model', 'uncertainty'), tracked=True, source=True),
    Workflow('fleet',
             "One view of the fleet: every machine axis's backlash now, trend, change points, "
             "threshold crossing and next visit due, worst first, with a static site (--out). Exit 3 "
             "when an alert fires.",
             inputs=('data',), tracked=True, source=True),
    Workflow('discover',
             'Find where simulation and measurement disagree, name the missing physical effect, add '
             'it and show the gap shrink.',
             inputs=('data',), tracked=True),
    Workflow('hidden-effects',
             'Benchmark the missing-effect workflow on twin data in which effects were hidden.',
             inputs=('scenarios',), tracked=True),
    Workflow('compensate',
             'Write compensation files for CNC controllers, 3D-printer firmware or CSV (--controller '
             'lists them) from ISO tests or a predictor; optionally re-measure the twin with them '
             'applied.',
             inputs=('data', 'active'), records='pipeline.store.records.record_compensation'),
    Workflow('uncertainty',
             'ISO/TR 230-9 measurement-uncertainty budget of a positioning test: each contributor, '
             'u_P and the expanded uncertainties of A, E, M, R, R+/R- and B.',
             inputs=('budget',)),
    Workflow('volumetric',
             "The seed paper's volumetric compensation on the machine twin: the 21 geometric errors "
             "identified off the tool point, compensated with the traditional and the Abbe-aware "
             "model, the four body diagonals before and after."),
    Workflow('circle',
             'ISO 230-4 circular tests (ballbar): circular deviation G per direction, hysteresis H '
             'and the diagnosis per axis (backlash, reversal spike) and per plane (squareness, scale '
             'and servo mismatch), each with its uncertainty; polar plots.',
             inputs=('data',), records='pipeline.store.records.record_ballbar'),
    Workflow('stiffness',
             'Static stiffness from loaded double-ballbar (LDBB) circles: per centre the stiffness '
             'in X and Y and the compliance with their uncertainty, a map over the workspace chosen '
             'by cross-validation, and the deflection under given forces (--at).',
             inputs=('data', 'at'), records='pipeline.store.records.record_stiffness'),
    Workflow('kinematics',
             "Five-axis rotary axes from probed spheres: seed 003's 12 geometric errors of a dual "
             'turntable with their uncertainty (inseparable ones named, never split), each '
             "rotary axis's play and the error field over the workspace.",
             inputs=('data', 'at'), records='pipeline.store.records.record_probing'),
    Workflow('monitor',
             'Lost motion per machine axis and day from controller traces with motor- and load-side '
             'positions, with its uncertainty, change points and trend.',
             inputs=('traces',), records='pipeline.store.records.record_trace'),
    Workflow('watch',
             "Lost motion per machine axis and day from a live controller feed (EPICS CA or PVA, "
             "OPC UA, a growing camonitor log), recorded in a fleet store as each day ends.",
             inputs=('config',), store_access='record'),
)
NAMES = tuple(w.name for w in WORKFLOWS)
_BY_NAME = {w.name: w for w in WORKFLOWS}


def workflow(name: str) -> Workflow:
    """The record of job ``name``."""
    if name not in _BY_NAME:
        raise InputError(f"unknown job {name!r}; expected one of {', '.join(NAMES)}",
                         parameter="name")
    return _BY_NAME[name]


def register(record: Workflow) -> Workflow:
    """Add a job from a package of its own (``record.module_name``): the CLI's command, the
    Python name ``bl.<job>``, experiment steps and the docs read it from then on, as they read
    the records above (read ``pipeline.workflows.NAMES`` when needed, not copied at import).

    Raises
    ------
    ValueError
        When a job of that name exists already.
    """
    global WORKFLOWS, NAMES, _BY_NAME
    if record.name in _BY_NAME:
        raise ValueError(f"job {record.name!r} exists already")
    WORKFLOWS = (*WORKFLOWS, record)
    NAMES, _BY_NAME = (*NAMES, record.name), {**_BY_NAME, record.name: record}
    return record


def unregister(name: str) -> None:
    """Remove job ``name`` (one added by ``register``)."""
    global WORKFLOWS, NAMES, _BY_NAME
    workflow(name)
    WORKFLOWS = tuple(w for w in WORKFLOWS if w.name != name)
    NAMES = tuple(w.name for w in WORKFLOWS)
    _BY_NAME = {w.name: w for w in WORKFLOWS}
