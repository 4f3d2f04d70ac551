"""MLflow glue: the one place that decides where runs, models, artifacts and studies go.

One rule: everything the product tracks goes to the **tracking folder**, the CLI's
``--tracking-dir DIR``, else ``BACKLASH_TRACKING_DIR``, else the working directory: the MLflow
database ``mlflow.db``, the artifacts ``mlartifacts/`` and the Optuna studies ``optuna.db``
(``tracking_dir``). A part given explicitly overrides it: ``MLFLOW_TRACKING_URI`` (a SQLite
file, a database URL, or ``http://HOST:PORT`` of a shared ``mlflow server``),
``BACKLASH_ARTIFACTS``, and ``tune``'s ``storage``; against a server without
``BACKLASH_ARTIFACTS`` artifacts go where the server stores them. ``check_uri`` says once,
as a note, where a command that finds no store yet will create it. ``configure()`` applies this
once per store; every other function here calls it, so commands never set URIs.

Quiet by default: MLflow's messages and log lines (and alembic's, which MLflow routes the same
way) are off unless the user asked for them (``features.readings.errors.verbose``: the CLI's
``--verbose``, ``BACKLASH_VERBOSE``, or a logging configuration of their own).

``log_result(result)`` is the one adapter from a workflow's result to MLflow: it logs the result's
``tracking_record()`` (params, metrics, artifacts, tags, a model to register, nested runs) and
gives the champion alias to the best model it registered. Registry convention: one registered
model, ``backlash-predictor``, whose versions carry tags (``data_sha256``, ``predictor``,
``target_kind``, the machine axes, ``backtest_skill``); the ``champion`` alias moves only
between versions with the same ``data_sha256`` (``promote_if_best``).

Concurrency: the first use of a fresh store (schema creation and migration) happens under a
file lock (in the temporary folder, keyed by the database's path, so no lock file is left
beside the user's files), or an advisory lock in PostgreSQL, so several processes may
start on an empty store at once; experiments created concurrently resolve to one; ``exclusive()`` is a mutex held in the
model registry itself (a unique registered-model name), so it works against any store,
including a remote server, and is used for compare-and-set decisions such as the champion.

mlflow is imported inside the functions so that the CLI starts fast.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import random
import re
import tempfile
import time
from dataclasses import fields
from pathlib import Path

from models.serving.description import FIGURES
from pipeline.results import TrackingRecord
from pipeline.tracking import TRACKING_DIR  # the tracking folder's variable (--tracking-dir)

DEFAULT_URI = "sqlite:///mlflow.db"
DEFAULT_ARTIFACTS = "mlartifacts"
DEFAULT_STUDIES = "optuna.db"
REMOTE_SCHEMES = ("http", "https", "databricks")
DATABASE_SCHEMES = ("sqlite", "postgresql", "mysql", "mssql")
MAX_KEY = 250  # MLflow's limit on metric and parameter names
MAX_VALUE = 6000  # MLflow's limit on parameter values
_BAD_KEY_CHARS = re.compile(r"[^\w.\- /]")
_ready: set[str] = set()
_silenced = False  # MLflow's messages are off in this process (``_silence_mlflow``)
_LOCK_KEY = 0x6261636B6C617368  # "backlash": the advisory lock guarding schema creation


def tracking_dir() -> Path | None:
    """The tracking folder ``BACKLASH_TRACKING_DIR`` (absolute), or None: the working
    directory."""
    folder = os.environ.get(TRACKING_DIR)
    return Path(folder).absolute() if folder else None


def tracking_uri() -> str:
    """``MLFLOW_TRACKING_URI``, else ``mlflow.db`` in the tracking folder."""
    folder = tracking_dir()
    return (os.environ.get("MLFLOW_TRACKING_URI")
            or (f"sqlite:///{folder / 'mlflow.db'}" if folder else DEFAULT_URI))


def artifact_root() -> Path:
    """``BACKLASH_ARTIFACTS``, else ``mlartifacts`` in the tracking folder."""
    folder = tracking_dir() or Path()
    return Path(os.environ.get("BACKLASH_ARTIFACTS") or folder / DEFAULT_ARTIFACTS).absolute()


def study_storage() -> str:
    """The default Optuna storage: ``optuna.db`` in the tracking folder."""
    folder = tracking_dir()
    return f"sqlite:///{folder / DEFAULT_STUDIES}" if folder else f"sqlite:///{DEFAULT_STUDIES}"


def where_note() -> str | None:
    """Where a command that finds no local MLflow store yet will create it, with the rule
    (one line), or None when the store exists or is not a local file."""
    path = _sqlite_path(tracking_uri()) if _scheme(tracking_uri()) == "sqlite" else None
    if path is None or path.exists():
        return None
    studies = study_storage().removeprefix("sqlite:///")
    return (f"tracking into a new MLflow store {path} (artifacts {artifact_root()}, Optuna "
            f"studies {Path(studies).absolute()}); --tracking-dir DIR or {TRACKING_DIR} "
            "chooses the folder")


def check_uri(uri: str | None = None) -> str:
    """The tracking URI if it names a store MLflow can open, else ``InputError`` in one line.

    Cheap (no mlflow import), so commands call it before they compute or write anything.
    """
    from features.readings.errors import InputError

    folder = tracking_dir()
    if folder is not None and not folder.is_dir():
        raise InputError(f"tracking folder {folder} ({TRACKING_DIR}, --tracking-dir) must be "
                         "an existing folder")
    uri = uri or tracking_uri()
    scheme = _scheme(uri)
    if scheme == "sqlite":
        path = _sqlite_path(uri)
        if path is None:
            raise InputError(f"MLFLOW_TRACKING_URI {uri!r} is not a SQLite file; expected "
                             "sqlite:///FILE (an in-memory store keeps nothing)")
        if path.is_dir() or not path.parent.is_dir():
            raise InputError(f"MLFLOW_TRACKING_URI {uri!r}: {path.parent} must be an existing "
                             "folder and the file not a folder")
        if not path.exists():  # said once: the next command finds the store
            from features.readings.errors import note

            note(where_note())
        return uri
    if scheme in REMOTE_SCHEMES + DATABASE_SCHEMES[1:] + ("file",) or "://" not in uri:
        return uri  # a plain path is MLflow's file store
    raise InputError(f"MLFLOW_TRACKING_URI {uri!r} is not a tracking store; expected "
                     "sqlite:///FILE, http(s)://HOST:PORT of an mlflow server, or "
                     "postgresql://USER@HOST/DB")


def _scheme(uri: str) -> str:
    """``sqlite`` of ``sqlite:///x``, ``postgresql`` of ``postgresql+psycopg2://...``."""
    return uri.split(":", 1)[0].split("+", 1)[0].lower() if "://" in uri else ""


def _sqlite_path(uri: str) -> Path | None:
    path = uri.split("sqlite:///", 1)[1] if uri.startswith("sqlite:///") else ""
    path = path.split("?", 1)[0]
    if not path or path == ":memory:" or path.startswith("file::memory:"):
        return None
    return Path(path).absolute()


def mlflow_module():
    """mlflow, with the tracking and registry URI set from the environment and the store
    created (under a lock when it is a fresh local file)."""
    mlflow = import_store()
    uri = check_uri()
    if mlflow.get_tracking_uri() != uri:
        mlflow.set_tracking_uri(uri)
    if mlflow.get_registry_uri() != uri:
        mlflow.set_registry_uri(uri)
    if uri not in _ready:
        _create_store(mlflow, uri)
        _ready.add(uri)
    return mlflow


configure = mlflow_module


def import_store():
    """Import mlflow and the modules its store needs for the configured URI, touching nothing
    on disk; returns mlflow. Lets a process pay the imports before it knows it will log.

    The product sends no usage data: MLflow's telemetry is switched off here unless the user
    set ``MLFLOW_DISABLE_TELEMETRY`` explicitly. MLflow's per-file progress bars, which flash
    by for the few small files of a model, are off unless the user turned them on, and so are
    its messages and log lines (``Creating initial MLflow database tables``, ``Created version
    '3' of model``) unless the user asked for them (``features.readings.errors.verbose``).
    """
    from features.readings.errors import verbose

    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    import mlflow

    if not verbose():
        _silence_mlflow()

    if _scheme(tracking_uri()) in DATABASE_SCHEMES:
        import mlflow.store.model_registry.sqlalchemy_store
        import mlflow.store.tracking.sqlalchemy_store
    return mlflow


def _silence_mlflow() -> None:
    """MLflow's messages and log lines (and alembic's, which go the same way) off for the rest
    of the process, the way MLflow silences them itself: a count of silencing contexts, held
    open here, so that MLflow's own nested ones (entered and left by some of its lazy imports)
    never switch them back on. ``disable_logging`` alone is undone by the first of those."""
    global _silenced
    if _silenced:
        return
    from mlflow.utils import logging_utils

    try:
        from mlflow.utils.autologging_utils.logging_and_warnings import (
            MlflowEventsAndWarningsBehaviorGlobally as Behaviour,
        )
    except ImportError:  # a version without it: off until MLflow turns them on again
        logging_utils.disable_logging()
    else:
        Behaviour(disable_event_logs=True, disable_warnings=False,
                  reroute_warnings=False).__enter__()
    _silenced = True


def prepare_model_logging() -> None:
    """Do ahead what logging the first model in a process costs besides the store: import
    ``mlflow.pyfunc`` and build MLflow's map of installed packages to their modules, which
    ``log_model`` reads to check the model's requirements against the installed versions
    (it reads the file list of every installed package: about half a second). A process
    that waits for a model to log (``pipeline.tracking.background``) calls it while it waits."""
    import mlflow.pyfunc  # noqa: F401
    from mlflow.utils import requirements_utils

    build = getattr(requirements_utils, "_init_modules_to_packages_map", None)
    if build is not None:  # a private cache of MLflow's: a version without it builds its own
        build()


def client():
    """An ``MlflowClient`` on the configured store."""
    return mlflow_module().MlflowClient()


def _create_store(mlflow, uri: str) -> None:
    """Open the tracking and registry stores once; their first opening creates and migrates
    the schema, which two processes must not do at the same time on one SQLite file."""
    path = _sqlite_path(uri) if uri.startswith("sqlite:") else None
    if path is not None:
        lock = _file_lock(lock_path(path))
    elif uri.startswith("postgresql"):
        lock = _advisory_lock(uri)
    else:  # a server creates its schema once at start; other databases are not locked
        lock = contextlib.nullcontext()
    with lock:
        store = mlflow.MlflowClient(uri, uri)
        store.search_experiments(max_results=1)
        store.search_registered_models(max_results=1)


def lock_path(database: Path) -> Path:
    """The lock file guarding the schema creation of a SQLite store: in the temporary folder,
    named by a hash of the database's absolute path (every process on this machine finds the
    same one; the user's working folder stays clean)."""
    name = hashlib.sha256(str(Path(database).absolute()).encode()).hexdigest()[:24]
    return Path(tempfile.gettempdir()) / f"backlash-mlflow-{name}.lock"


def _file_lock(path: Path):
    from filelock import FileLock

    return FileLock(str(path), timeout=300, mode=0o666)  # shared by every user of the store


@contextlib.contextmanager
def _advisory_lock(uri: str):
    """PostgreSQL session-level advisory lock, held by a connection of its own."""
    import sqlalchemy

    engine = sqlalchemy.create_engine(uri, poolclass=sqlalchemy.pool.NullPool)
    try:
        with engine.connect() as conn:
            conn.execute(sqlalchemy.text("SELECT pg_advisory_lock(:k)"), {"k": _LOCK_KEY})
            try:
                yield
            finally:
                conn.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:k)"), {"k": _LOCK_KEY})
    finally:
        engine.dispose()


def artifact_location(name: str) -> str | None:
    """Where a new experiment keeps its artifacts: the project folder, or, against a server
    and without ``BACKLASH_ARTIFACTS``, the server's own artifact store (None)."""
    remote = tracking_uri().split(":", 1)[0].lower() in REMOTE_SCHEMES
    if remote and not os.environ.get("BACKLASH_ARTIFACTS"):
        return None
    return (artifact_root() / name).as_uri()


def experiment_id(name: str) -> str:
    """Id of the named experiment, created with the project's artifact folder if new; two
    processes creating it at once both get the same one."""
    mlflow = mlflow_module()
    from mlflow.exceptions import MlflowException

    for _ in range(5):
        found = mlflow.get_experiment_by_name(name)
        if found is not None:
            return found.experiment_id
        try:
            return mlflow.create_experiment(name, artifact_location=artifact_location(name))
        except MlflowException as err:
            if err.error_code != "RESOURCE_ALREADY_EXISTS":
                raise
    raise RuntimeError(f"experiment {name!r} neither found nor created")


@contextlib.contextmanager
def run(experiment: str, run_name: str, *, nested: bool = False, tags: dict | None = None):
    """Start an MLflow run in ``experiment``; nests under an active run when asked."""
    mlflow = mlflow_module()
    exp_id = experiment_id(experiment)
    active = mlflow.active_run()
    nest = nested or active is not None
    with mlflow.start_run(experiment_id=exp_id, run_name=run_name[:MAX_VALUE], nested=nest,
                          tags=tags) as current:
        yield current


def key(name: str) -> str:
    """``name`` as a valid MLflow metric or parameter name.

    Characters MLflow refuses (``#``, ``<``, quotes, ...) become ``_``; path-like names that
    MLflow would resolve to other names (``a//b``, ``../x``, ``/x``) are flattened. A name
    that had to change gets a short hash of the original, so two ids that differ only in
    refused characters stay two metrics.
    """
    clean = _BAD_KEY_CHARS.sub("_", str(name))
    parts = [p if p not in (".", "..") else p.replace(".", "_") for p in clean.split("/")]
    clean = "/".join(p for p in parts if p) or "_"
    if clean == str(name) and len(clean) <= MAX_KEY:
        return clean
    digest = hashlib.sha1(str(name).encode()).hexdigest()[:8]
    return f"{clean[:MAX_KEY - 9]}-{digest}"


def params(values: dict) -> dict:
    """Parameters with valid names and values within MLflow's length limit."""
    return {key(k): str(v)[:MAX_VALUE] for k, v in values.items()}


def metrics(values: dict) -> dict:
    """Finite metrics with valid names (MLflow refuses NaN in some stores and inf in others)."""
    import math

    out = {}
    for k, v in values.items():
        try:
            value = float(v)
        except (TypeError, ValueError):
            continue
        if math.isfinite(value):
            out[key(k)] = value
    return out


@contextlib.contextmanager
def exclusive(name: str, *, wait_s: float = 120.0, lease_s: float = 60.0):
    """Mutex across processes and machines sharing the store: held while the registered model
    ``name`` exists (creating it is atomic in every store).

    A holder killed inside the critical section leaves the lock behind; a waiter that has
    seen the same lock for ``lease_s`` seconds removes it (the critical sections it guards
    take well under a second).
    """
    from mlflow.exceptions import MlflowException

    store = client()
    start = time.monotonic()
    seen, since = None, start
    while True:
        try:
            store.create_registered_model(name, description="lock; removed when released")
            break
        except MlflowException as err:
            if err.error_code not in ("RESOURCE_ALREADY_EXISTS", "RESOURCE_DOES_NOT_EXIST"):
                raise
        holder = _lock_stamp(store, name)
        now = time.monotonic()
        if holder != seen:
            seen, since = holder, now
        elif holder is not None and now - since > lease_s:
            _drop(store, name)
            continue
        if now - start > wait_s:
            raise TimeoutError(f"lock {name!r} still held after {wait_s:.0f} s")
        time.sleep(random.uniform(0.05, 0.2))  # jitter: waiters do not retry in lockstep
    try:
        yield
    finally:
        _drop(store, name)


def _lock_stamp(store, name: str):
    from mlflow.exceptions import MlflowException

    try:
        return store.get_registered_model(name).creation_timestamp
    except MlflowException:
        return None


def _drop(store, name: str) -> None:
    from mlflow.exceptions import MlflowException

    with contextlib.suppress(MlflowException):
        store.delete_registered_model(name)


# --------------------------------------------------------------------------- the one adapter

def record_data(record: TrackingRecord) -> dict:
    """``record`` as plain JSON data (paths as text), for another process to log."""
    data = {f.name: getattr(record, f.name) for f in fields(record)}
    data["artifacts"] = [str(path) for path in record.artifacts]
    data["children"] = [record_data(child) for child in data.get("children", [])]
    return data


def log_result(result, *, nested: bool = False) -> dict:
    """Log a workflow result (or a ``TrackingRecord``) to MLflow: one run in the record's
    experiment, nested under an active run, its children nested under it.

    Returns
    -------
    dict
        ``run_id``; ``version`` and ``champion`` when a model was registered; ``children``: the
        same per nested run, by run name. Empty when the result is not tracked.
    """
    record = result if isinstance(result, TrackingRecord) else result.tracking_record()
    if record is None:
        return {}
    data = record_data(record)
    with run(data["experiment"], data["run_name"], nested=nested, tags=data["tags"] or None) \
            as active:
        return {"run_id": active.info.run_id, **log_into(data)}


def log_into(data: dict) -> dict:
    """Log a record (``record_data``) into the active run; the logging function of
    ``pipeline.tracking.background`` (plain data in, plain data out)."""
    mlflow = mlflow_module()
    if data.get("params"):
        mlflow.log_params(params(data["params"]))
    if data.get("metrics"):
        mlflow.log_metrics(metrics(data["metrics"]))
    for path in data.get("artifacts", []):
        mlflow.log_artifact(path, artifact_path=data.get("artifact_path"))
    out = {}
    if data.get("model"):
        out["version"] = log_model(data["model"])
    children = {}
    for child in data.get("children", []):
        if child.get("status", "FINISHED") != "FINISHED":  # a failed trial: ended as FAILED
            parent = mlflow.active_run().info
            children[child["run_name"]] = {"run_id": log_child(
                parent.experiment_id, parent.run_id, child)}
            continue
        with run(data["experiment"], child["run_name"], nested=True,
                 tags=child.get("tags") or None) as active:
            children[child["run_name"]] = {"run_id": active.info.run_id, **log_into(child)}
    if children:
        out["children"] = children
    if data.get("promote"):
        out["champion"] = _promote_best(data, out)
    return out


def _promote_best(data: dict, logged: dict) -> bool:
    """Champion alias for the best registered model among the record and its children
    (``standing``: forecasting skill first, then the held-out RMSE)."""
    import math

    candidates = []
    records = [(data, logged.get("version"))] + [
        (child, logged.get("children", {}).get(child["run_name"], {}).get("version"))
        for child in data.get("children", [])]
    for record, version in records:
        if version is not None:
            skill = (record.get("model") or {}).get("backtest", {}).get("skill")
            rmse = record["metrics"].get("test_rmse_um", math.inf)
            candidates.append((standing(skill, rmse), skill, rmse, version))
    if not candidates:
        return False
    _, skill, rmse, version = max(candidates, key=lambda c: c[0])
    return promote_if_best(version, str(data["params"]["data_sha256"]), float(rmse), skill)


def log_child(experiment_id: str, parent_run_id: str, record) -> str:
    """Log ``record`` (a ``TrackingRecord`` or its ``record_data``: params, metrics, tags,
    status) as a run nested under ``parent_run_id`` and ended at once, from any process (no
    active run needed); returns its run id."""
    from mlflow.entities import Metric, Param, RunStatus
    from mlflow.utils.time import get_current_time_millis

    data = record if isinstance(record, dict) else record_data(record)
    store = client()
    created = store.create_run(experiment_id, run_name=data["run_name"],
                               tags={"mlflow.parentRunId": parent_run_id, **data["tags"]})
    now = get_current_time_millis()
    store.log_batch(created.info.run_id,
                    metrics=[Metric(k, v, now, 0) for k, v in metrics(data["metrics"]).items()],
                    params=[Param(k, v) for k, v in params(data["params"]).items()])
    finished = data.get("status", "FINISHED") == "FINISHED"
    store.set_terminated(created.info.run_id, RunStatus.to_string(
        RunStatus.FINISHED if finished else RunStatus.FAILED))
    return created.info.run_id


def end_killed(experiment: str, tags) -> list[str]:
    """End as KILLED the runs of ``experiment`` still RUNNING (their process was killed) whose
    ``tag`` parameter is one of ``tags``, nested runs aside; returns their run ids."""
    tags = set(tags) - {None}
    if not tags:
        return []
    store = client()
    found = store.get_experiment_by_name(experiment)
    if found is None:
        return []
    closed = []
    for run_ in store.search_runs([found.experiment_id], "attributes.status = 'RUNNING'"):
        if run_.data.params.get("tag") in tags and "mlflow.parentRunId" not in run_.data.tags:
            store.set_terminated(run_.info.run_id, "KILLED")
            closed.append(run_.info.run_id)
    return closed


class LiveRun:
    """The run of a job that logs while it computes (``Workflow.logs_while_running``; the
    runner enters it around the job and hands it to the job as ``live``).

    The job ``start``s it once its record is known; each step it hands to ``child`` (from any
    process) is a nested run at once, so a job killed later keeps what it finished (and its
    run stays RUNNING, to be ended as KILLED by the next job that ``start``s with its
    ``tag``); the runner ``finish``es it with the result. Leaving the context ends the run:
    FINISHED, or FAILED on an error.
    """

    def __init__(self, job: str):
        self.job = job
        self._stack = contextlib.ExitStack()
        self._active = None
        self._started: dict = {}

    def __enter__(self):
        check_uri()  # a bad tracking store is refused before any work
        return self

    def __exit__(self, *exc_info):
        return self._stack.__exit__(*exc_info)

    def start(self, record: TrackingRecord, killed=()) -> list[str]:
        """Start the run: ``record``'s experiment, run name, tags and params (logged at once).
        Before, the runs of earlier jobs that were killed (``end_killed`` of ``killed``) are
        ended as KILLED; returns the notes saying so."""
        closed = end_killed(record.experiment, killed)
        self._active = self._stack.enter_context(
            run(record.experiment, record.run_name, tags=record.tags or None))
        mlflow_module().log_params(params(record.params))
        self._started = dict(record.params)
        return ([f"MLflow run(s) {', '.join(closed)} of killed searches ended as KILLED"]
                if closed else [])

    @property
    def child(self):
        """``child(record)``: ``record`` logged as a run nested under this one and ended at
        once (``log_child``), from this process or another (it pickles)."""
        info = self._active.info
        return functools.partial(log_child, info.experiment_id, info.run_id)

    def finish(self, result) -> dict:
        """Log ``result``'s ``tracking_record()`` into the run: the params ``start`` did not
        log, the metrics and artifacts (the children went to ``child`` as they came); returns
        ``run_id``. Nothing when the job never started the run."""
        if self._active is None:
            return {}
        record = result if isinstance(result, TrackingRecord) else result.tracking_record()
        if record is not None:
            data = record_data(record)
            data["params"] = {k: v for k, v in data["params"].items() if k not in self._started}
            log_into({**data, "children": []})
        return {"run_id": self._active.info.run_id}


# --------------------------------------------------------------------------- model registry

REGISTERED_NAME = "backlash-predictor"
CHAMPION = "champion"
CHAMPION_LOCK = f"{REGISTERED_NAME}.champion-lock"
MODEL_FIGURES = FIGURES  # the folder of a model directory holding its figures
BACKTEST_METRICS = ("skill", "rmse_um", "persistence_rmse_um")  # logged as backtest_*
REQUIREMENTS = ["backlash-pipeline", "torch==2.13.0", "mlflow>=3.17,<3.18", "scikit-learn",
                "skops", "pandas", "numpy", "scipy"]


def log_model(model: dict) -> str:
    """Log a trained model (a record's ``model``: its result's ``models.serving.description.describe``
    with its ``model_dir``) into the active run: its estimator parameters, per-epoch history,
    backtest scores (``backtest_skill``, ``backtest_rmse_um``, ``backtest_persistence_rmse_um``),
    the model directory and the model from code, registered as ``backlash-predictor`` with the
    record's version tags; returns the registered version."""
    import shutil

    mlflow = mlflow_module()
    mlflow.log_params(params(model["estimator_params"]))
    for name, values in model["history"].items():
        for epoch, value in enumerate(values):
            if value is not None:
                mlflow.log_metric(key(f"epoch_{name}"), value, step=epoch)
    scores = model.get("backtest", {})
    mlflow.log_metrics(metrics({f"backtest_{k}": scores[k] for k in BACKTEST_METRICS
                                if scores.get(k) is not None}))
    with tempfile.TemporaryDirectory() as tmp:
        # a copy without figures/: they are logged apart, under their own artifact path
        model_dir = shutil.copytree(model["model_dir"], Path(tmp) / "model_dir",
                                    ignore=shutil.ignore_patterns(MODEL_FIGURES))
        mlflow.log_artifacts(str(model_dir), artifact_path="model_dir")
        version = _log_pyfunc(model, model_dir).registered_model_version
    return str(version)


def signature(spec: dict):
    """The MLflow ``ModelSignature`` of a record's ``signature`` (plain data): one column per
    input (conditions a plan may omit optional) and one column per output (``double``; the
    ``extrapolated`` inputs and a fleet's ``borrowed`` are text)."""
    from mlflow.models import ModelSignature
    from mlflow.types.schema import ColSpec, Schema

    from models.serving.signature import TEXT_OUTPUTS

    inputs = Schema([ColSpec(c["type"], c["name"], required=c["required"])
                     for c in spec["inputs"]])
    return ModelSignature(inputs=inputs, outputs=Schema([
        ColSpec("string" if name in TEXT_OUTPUTS else "double", name)
        for name in spec["outputs"]]))


def _log_pyfunc(model: dict, model_dir: Path):
    """The model from code, registered, with signature, input example and version tags.

    MLflow would also check that the example serves by loading the model into this process;
    that imports the predictor's libraries into a logging process that needs none of them
    (seconds per training), and the test suite checks the served model instead."""
    import pandas as pd
    from mlflow.models import Model

    example = pd.DataFrame(**model["example"])
    return Model.log(
        artifact_path=None, name="model", flavor=_PyfuncFlavor, flavor_name="pyfunc.ModelFromCode",
        python_model=str(Path(__file__).parents[2] / "models" / "serving"
                         / "pyfunc_model.py"),
        artifacts={"model_dir": str(model_dir)}, signature=signature(model["signature"]),
        input_example=example, registered_model_name=REGISTERED_NAME,
        tags=model.get("tags") or None,
        pip_requirements=REQUIREMENTS,  # explicit: inferring them costs seconds per model
        validate_serving_input=False)


class _PyfuncFlavor:
    """``mlflow.pyfunc`` as a flavor of ``Model.log``: ``Model.log`` reads its
    ``validate_serving_input`` switch and passes it on, which ``pyfunc.save_model`` refuses."""

    @staticmethod
    def save_model(*, validate_serving_input: bool = True, **kwargs):
        import mlflow.pyfunc

        return mlflow.pyfunc.save_model(**kwargs)


def promote_if_best(version: str, data_hash: str, rmse_um: float,
                    skill: float | None = None) -> bool:
    """Give ``version`` the champion alias when it beats the champion on the same data set
    (or there is none yet). A champion trained on other data is left alone.

    Better means (``standing``): a forecasting skill against persistence (version tag
    ``backtest_skill``) beats none; between two skills the higher wins; between two versions
    without one the lower held-out RMSE (run metric ``test_rmse_um``). Ties keep the champion.

    Compare-and-set under a registry-wide lock, so two trainings finishing at once cannot
    both read the old champion and both claim the alias.
    """
    with exclusive(CHAMPION_LOCK):
        return _promote(client(), version, data_hash, standing(skill, rmse_um))


def standing(skill: float | None, rmse_um: float) -> tuple:
    """Sort key of a registered version for the champion (higher is better): has a skill,
    the skill, minus the held-out RMSE."""
    return (skill is not None, skill if skill is not None else 0.0, -float(rmse_um))


def version_skill(tags: dict) -> float | None:
    """The ``backtest_skill`` version tag as a number; None for ``n/a: ...`` or no tag."""
    import math

    try:
        value = float(tags.get("backtest_skill", "n/a"))
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _promote(store, version: str, data_hash: str, candidate: tuple) -> bool:
    import math

    from mlflow.exceptions import MlflowException

    try:
        current = store.get_model_version_by_alias(REGISTERED_NAME, CHAMPION)
    except MlflowException:
        current = None
    if current is not None:
        found = store.get_run(current.run_id)
        tags = current.tags or {}
        if tags.get("data_sha256", found.data.params.get("data_sha256")) != data_hash:
            return False
        held = standing(version_skill(tags),
                        float(found.data.metrics.get("test_rmse_um", math.inf)))
        if held >= candidate:
            return False
    store.set_registered_model_alias(REGISTERED_NAME, CHAMPION, version)
    return True
