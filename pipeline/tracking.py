"""MLflow glue: the one place that decides where runs, models and artifacts go.

The tracking store is ``MLFLOW_TRACKING_URI`` (default ``sqlite:///mlflow.db`` in the working
directory): a local SQLite file, a database URL, or ``http://HOST:PORT`` of a shared
``mlflow server``. Artifacts go to ``BACKLASH_ARTIFACTS`` (default ``./mlartifacts``); against
a server without ``BACKLASH_ARTIFACTS`` they go where the server stores them. ``configure()``
applies this once per store; every other function here calls it, so commands never set URIs.

Concurrency: the first use of a fresh store (schema creation and migration) happens under a
file lock beside a SQLite database, or an advisory lock in PostgreSQL, so several processes may
start on an empty store at once; experiments created concurrently resolve to one; ``exclusive()`` is a mutex held in the
model registry itself (a unique registered-model name), so it works against any store,
including a remote server, and is used for compare-and-set decisions such as the champion.

mlflow is imported inside the functions so that the CLI starts fast.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import random
import re
import time
from pathlib import Path

DEFAULT_URI = "sqlite:///mlflow.db"
DEFAULT_ARTIFACTS = "mlartifacts"
REMOTE_SCHEMES = ("http", "https", "databricks")
DATABASE_SCHEMES = ("sqlite", "postgresql", "mysql", "mssql")
MAX_KEY = 250  # MLflow's limit on metric and parameter names
MAX_VALUE = 6000  # MLflow's limit on parameter values
_BAD_KEY_CHARS = re.compile(r"[^\w.\- /]")
_ready: set[str] = set()
_LOCK_KEY = 0x6261636B6C617368  # "backlash": the advisory lock guarding schema creation


def tracking_uri() -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or DEFAULT_URI


def artifact_root() -> Path:
    return Path(os.environ.get("BACKLASH_ARTIFACTS") or DEFAULT_ARTIFACTS).absolute()


def check_uri(uri: str | None = None) -> str:
    """The tracking URI if it names a store MLflow can open, else ``InputError`` in one line.

    Cheap (no mlflow import), so commands call it before they compute or write anything.
    """
    from features.readings.errors import InputError

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
    by for the few small files of a model, are off unless the user turned them on.
    """
    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    import mlflow

    if _scheme(tracking_uri()) in DATABASE_SCHEMES:
        import mlflow.store.model_registry.sqlalchemy_store
        import mlflow.store.tracking.sqlalchemy_store
    return mlflow


def client():
    """An ``MlflowClient`` on the configured store."""
    return mlflow_module().MlflowClient()


def _create_store(mlflow, uri: str) -> None:
    """Open the tracking and registry stores once; their first opening creates and migrates
    the schema, which two processes must not do at the same time on one SQLite file."""
    path = _sqlite_path(uri) if uri.startswith("sqlite:") else None
    if path is not None:
        lock = _file_lock(path.with_name(path.name + ".lock"))
    elif uri.startswith("postgresql"):
        lock = _advisory_lock(uri)
    else:  # a server creates its schema once at start; other databases are not locked
        lock = contextlib.nullcontext()
    with lock:
        store = mlflow.MlflowClient(uri, uri)
        store.search_experiments(max_results=1)
        store.search_registered_models(max_results=1)


def _file_lock(path: Path):
    from filelock import FileLock

    return FileLock(str(path), timeout=300)


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


def data_hash(frame) -> str:
    """Content hash of a data frame (sha256 of its canonical CSV bytes), logged with runs."""
    payload = frame.to_csv(index=False).encode()
    return hashlib.sha256(payload).hexdigest()
