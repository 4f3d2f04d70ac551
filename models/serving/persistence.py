"""One save/load protocol for every fitted estimator and every part of a composite one.

Three formats, chosen by ``save_estimator``:

- ``self``: the estimator's own ``save(directory)`` / ``load(directory)`` (torch state dicts
  read with ``weights_only=True``, JSON coefficients, composites writing their parts);
- ``json``: constructor parameters and fitted attributes that are plain numbers, strings and
  numeric arrays (the physics baselines) — read back without importing skops;
- ``skops``: anything else (scikit-learn's own estimators).

Loading never unpickles and never trusts a type because of the module it lives in:

- the caller passes a *template*, the unfitted estimator the registry builds for the model's
  name; a ``self`` or ``json`` part must be of the template's exact class (or, for a part of a
  composite, of the class of the template's parameter), and the class object is taken from the
  template, never imported by a name read from disk;
- a skops file is read once into memory, its sha256 checked, and every node of its tree
  checked against ``SKOPS_TYPES`` (exact type names) and ``SKOPS_LOADERS`` — plus
  ``skops.io.get_untrusted_types`` — before anything is constructed;
- part paths are relative, inside the model directory, free of ``..`` and of symlinks that
  lead out;
- each part's sha256 is stored in the spec and checked before the part is read.

A spec (returned by ``save_estimator``, kept by the caller in its own JSON) is
``{"format", "class", "path", "sha256"}``; ``check_spec`` validates one read from disk.
Every problem is an ``InputError`` naming the file.

An estimator that saves itself (``self`` format) keeps its parameters and fitted state in one
JSON file, written by ``write_state`` (atomically, with the inputs it was fitted on) and read
back by ``read_state`` (every key it needs checked, no key error escapes) and
``restore_inputs``: the wear map, the physics hybrid and the bootstrap ensemble.
"""

from __future__ import annotations

import hashlib
import inspect
import io
import json
import re
import zipfile
from pathlib import Path, PurePosixPath

import numpy as np

from features.readings.errors import InputError
from features.readings.fileio import atomic_path, write_json
from models import current_name

SAVE_FORMATS = ("self", "json", "skops")
JSON_SUFFIX = ".json"
SKOPS_SUFFIX = ".skops"

# Every type that appears in the skops trees of the registry's skops-saved predictors (the
# k-NN and ridge pipelines, gradient boosting), exactly; tests/test_model_safety.py checks that
# this is all they need. No callables: a skops tree may name a function, never call one here.
SKOPS_TYPES = frozenset({
    "builtins.dict", "builtins.list", "builtins.tuple", "builtins.str",
    "numpy.ndarray", "numpy.float64",
    "numpy.random.mtrand.RandomState",
    "sklearn.pipeline.Pipeline",
    "sklearn.preprocessing._data.StandardScaler",
    "sklearn.neighbors._regression.KNeighborsRegressor",
    "sklearn.neighbors._kd_tree.KDTree",
    "sklearn.metrics._dist_metrics.EuclideanDistance64",
    "sklearn.linear_model._ridge.RidgeCV",
    "sklearn.ensemble._gb.GradientBoostingRegressor",
    "sklearn.tree._classes.DecisionTreeRegressor",
    "sklearn.tree._tree.Tree",
    "sklearn.dummy.DummyRegressor",
    "sklearn._loss.loss.HalfSquaredError",
    "sklearn._loss._loss.CyHalfSquaredError",
    "sklearn._loss.link.IdentityLink",
    "sklearn._loss.link.Interval",
})
# skops node kinds that rebuild data or an allowed object; function, method, partial and
# generic reduce nodes (the ones that can call something) are refused
SKOPS_LOADERS = frozenset({"DictNode", "ListNode", "TupleNode", "JsonNode", "TypeNode",
                           "NdArrayNode", "ObjectNode", "RandomStateNode", "TreeNode",
                           "LossNode", "CachedNode"})
_ARRAY_DTYPES = ("float64", "float32", "int64", "int32", "bool")
_SHA256 = re.compile(r"[0-9a-f]{64}")


def class_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


# ----------------------------------------------------------------------------- saving

def save_estimator(estimator, directory, name: str) -> dict:
    """Write ``estimator`` into ``directory`` under ``name``; return its spec."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    spec = {"class": class_name(type(estimator))}
    if hasattr(estimator, "save"):
        estimator.save(directory / name)
        spec |= {"format": "self", "path": name}
    elif (plain := _plain_state(estimator)) is not None:
        write_json(directory / f"{name}{JSON_SUFFIX}", plain)
        spec |= {"format": "json", "path": f"{name}{JSON_SUFFIX}"}
    else:
        import skops.io

        with atomic_path(directory / f"{name}{SKOPS_SUFFIX}") as tmp:
            skops.io.dump(estimator, tmp)
        spec |= {"format": "skops", "path": f"{name}{SKOPS_SUFFIX}"}
    spec["sha256"] = digest(directory / spec["path"])
    return spec


def digest(path: Path) -> str:
    """sha256 of a file, or of a folder: its files' relative paths and contents, in order."""
    path = Path(path)
    if path.is_file():
        return hashlib.sha256(path.read_bytes()).hexdigest()
    total = hashlib.sha256()
    for item in sorted(p for p in path.rglob("*") if p.is_file()):
        total.update(item.relative_to(path).as_posix().encode() + b"\0")
        total.update(hashlib.sha256(item.read_bytes()).digest())
    return total.hexdigest()


def _plain_state(estimator) -> dict | None:
    """Parameters and fitted attributes as JSON, or None when any is not plain data or the
    estimator keeps other state (private attributes) that JSON would lose."""
    params = estimator.get_params(deep=False)
    fitted = {k: v for k, v in vars(estimator).items() if k not in params}
    if any(not k.endswith("_") or k.startswith("_") for k in fitted):
        return None
    try:
        return {"params": {k: _encode(v) for k, v in params.items()},
                "state": {k: _encode(v) for k, v in fitted.items()}}
    except TypeError:
        return None


def _encode(value):
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (np.bool_, np.integer, np.floating)):
        return value.item()
    if isinstance(value, (tuple, list)):
        return {"tuple" if isinstance(value, tuple) else "list": [_encode(v) for v in value]}
    if isinstance(value, np.ndarray):
        if value.dtype == object and all(isinstance(v, str) for v in value.ravel()):
            return {"strings": value.tolist()}
        if value.dtype.name in _ARRAY_DTYPES:
            return {"array": value.tolist(), "dtype": value.dtype.name}
    raise TypeError(f"not plain data: {type(value).__name__}")


def _decode(value):
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, dict) and len(value) == 1 and isinstance(
            items := next(iter(value.values())), list):
        kind = next(iter(value))
        if kind == "tuple":
            return tuple(_decode(v) for v in items)
        if kind == "list":
            return [_decode(v) for v in items]
        if kind == "strings" and all(isinstance(v, str) for v in items):
            return np.asarray(items, dtype=object)
    if (isinstance(value, dict) and set(value) == {"array", "dtype"}
            and value["dtype"] in _ARRAY_DTYPES):
        return np.asarray(value["array"], dtype=value["dtype"])
    raise ValueError(f"unexpected value {str(value)[:60]!r}")


# ----------------------------------------------------------------------------- JSON state

INPUT_KEYS = ("n_features_in", "feature_names_in")


def fitted_inputs(estimator) -> dict:
    """The inputs ``estimator`` was fitted on, as JSON: their number and names (if any)."""
    return {"n_features_in": int(estimator.n_features_in_),
            "feature_names_in": [str(c) for c in getattr(estimator, "feature_names_in_", [])]}


def write_state(path, estimator, state: dict) -> Path:
    """Write ``state`` and the inputs ``estimator`` was fitted on to the JSON file ``path``,
    atomically (a reader never sees half a file)."""
    return write_json(path, {**state, **fitted_inputs(estimator)})


def read_state(path, keys=()) -> dict:
    """The JSON object written by ``write_state`` at ``path``, with ``keys`` (and the fitted
    inputs) present; anything else is an ``InputError`` naming the file."""
    path = Path(path)
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"model folder has no {path.name}", file=path) from None
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError(f"broken {path.name}: {err}", file=path) from None
    if not isinstance(state, dict):
        raise InputError(f"broken {path.name}: expected a JSON object, found "
                         f"{type(state).__name__}", file=path)
    for key in (*keys, *INPUT_KEYS):
        if key not in state:
            raise InputError(f"broken {path.name}: lacks the key {key!r}", file=path)
    names = state["feature_names_in"]
    if (isinstance(state["n_features_in"], bool) or not isinstance(state["n_features_in"], int)
            or not isinstance(names, list) or not all(isinstance(c, str) for c in names)):
        raise InputError(f"broken {path.name}: n_features_in must be a number and "
                         "feature_names_in a list of names", file=path)
    return state


def restore_inputs(model, state: dict):
    """Set ``n_features_in_`` and ``feature_names_in_`` of ``model`` from ``read_state``'s
    result; returns ``model``."""
    model.n_features_in_ = int(state["n_features_in"])
    if state["feature_names_in"]:
        model.feature_names_in_ = np.asarray(state["feature_names_in"], dtype=object)
    return model


def checked_params(model, where):
    """``model`` once its parameters (read from disk) pass its declared constraints
    (``_parameter_constraints``); an ``InputError`` naming ``where`` otherwise."""
    try:
        model._validate_params()
    except ValueError as err:
        raise InputError(f"saved parameters are invalid: {err}", file=where) from None
    return model


# ----------------------------------------------------------------------------- loading

def check_spec(spec, where) -> dict:
    """The spec of a part as read from JSON, validated (``where`` names the JSON file)."""
    if not isinstance(spec, dict):
        raise InputError("expected a part description (format, class, path, sha256)",
                         file=where)
    for key in ("format", "class", "path", "sha256"):
        if not isinstance(spec.get(key), str):
            raise InputError(f"part description lacks the text key {key!r}", file=where)
    if spec["format"] not in SAVE_FORMATS:
        raise InputError(f"unknown part format {spec['format']!r}; expected one of "
                         f"{', '.join(SAVE_FORMATS)}", file=where)
    if not _SHA256.fullmatch(spec["sha256"]):
        raise InputError("part sha256 is not 64 hexadecimal digits", file=where)
    return spec


def confined(directory, relative: str, where=None) -> Path:
    """``directory / relative``, refused unless it stays inside ``directory``: no absolute
    path, no ``..``, no symlink on the way or inside a part folder that leads out."""
    directory = Path(directory)
    pure = PurePosixPath(relative)
    if (not relative or pure.is_absolute() or "\\" in relative or ":" in relative
            or ".." in pure.parts):
        raise InputError(f"part path {relative!r} must be a plain name inside the model "
                         "directory", file=where or directory)
    root = directory.resolve()
    path = directory.joinpath(*pure.parts)
    inside = [path, *(path.rglob("*") if path.is_dir() and not path.is_symlink() else [])]
    for item in inside:
        if not item.resolve().is_relative_to(root):
            raise InputError(f"part path {relative!r} leads outside the model directory",
                             file=where or directory)
    return path


def load_estimator(directory, spec: dict, template, where=None):
    """Read back a part written by ``save_estimator`` (see the module docstring).

    ``template`` is the unfitted estimator the part must be an instance of;
    ``where`` is the JSON file that holds ``spec`` (named in errors).
    """
    where = where or Path(directory)
    spec = check_spec(spec, where)
    path = confined(directory, spec["path"], where)
    if not path.exists():
        raise InputError(f"model part {spec['path']!r} is missing", file=where)
    if current_name(spec["class"]) != class_name(type(template)):
        raise InputError(f"refusing estimator class {spec['class']!r}; this model's entry "
                         f"builds {class_name(type(template))}", file=where)
    if spec["format"] == "skops":
        estimator = _load_skops(path, spec["sha256"], allowed=product_types(template))
        if type(estimator) is not type(template):
            raise InputError(f"the skops file holds a {type(estimator).__name__}, expected "
                             f"{type(template).__name__}", file=path)
        return estimator
    if digest(path) != spec["sha256"]:
        raise InputError(f"model part {spec['path']!r} does not match its sha256 "
                         "(changed or damaged since it was saved)", file=where)
    cls = type(template)
    try:
        if spec["format"] == "json":
            return _from_plain(cls, json.loads(path.read_text(encoding="utf-8")))
        if "template" in inspect.signature(cls.load).parameters:
            return cls.load(path, template=template)
        return cls.load(path)
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - any failure to read a part is a damaged part
        raise InputError(f"cannot read model part {spec['path']!r}: {err}", file=path) from None


def product_types(template) -> set[str]:
    """Exact class names of ``template`` and of the estimators among its parameters."""
    found = {class_name(type(template))}
    if hasattr(template, "get_params"):
        for value in template.get_params(deep=True).values():
            if hasattr(value, "fit"):
                found.add(class_name(type(value)))
    return found


def _from_plain(cls, plain: dict):
    if not isinstance(plain, dict) or set(plain) != {"params", "state"}:
        raise ValueError("expected the keys params and state")
    params = {k: _decode(v) for k, v in plain["params"].items()}
    unknown = set(params) - set(inspect.signature(cls).parameters)
    if unknown:
        raise ValueError(f"unknown parameter {min(unknown)!r}")
    estimator = cls(**params)
    for key, value in plain["state"].items():
        if not (key.endswith("_") and key.isidentifier() and not key.startswith("_")):
            raise ValueError(f"unexpected attribute {key!r}")
        setattr(estimator, key, _decode(value))
    return estimator


def _load_skops(path: Path, sha256: str, allowed: set[str]):
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != sha256:
        raise InputError("model part does not match its sha256 (changed or damaged since it "
                         "was saved)", file=path)
    for kind, type_name in skops_nodes(data, path):
        if kind not in SKOPS_LOADERS:
            raise InputError(f"refusing skops node {kind} ({type_name}): the product never "
                             "saves one", file=path)
        if type_name not in SKOPS_TYPES and current_name(type_name) not in allowed:
            raise InputError(f"refusing to load type {type_name!r}: not among the types the "
                             "product saves", file=path)
    import skops.io

    try:
        untrusted = skops.io.get_untrusted_types(data=data)
        refused = [t for t in untrusted
                   if t not in SKOPS_TYPES and current_name(t) not in allowed]
        if refused:
            raise InputError(f"refusing to load type {refused[0]!r}: not among the types the "
                             "product saves", file=path)
        return skops.io.loads(data, trusted=untrusted)
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - a damaged archive is a damaged part
        raise InputError(f"cannot read skops file: {err}", file=path) from None


def skops_nodes(data: bytes, path=None) -> list[tuple[str, str]]:
    """(loader, type name) of every node of a skops file's tree, read from its schema."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            schema = json.loads(archive.read("schema.json"))
    except (zipfile.BadZipFile, KeyError, ValueError) as err:
        raise InputError(f"not a readable skops file: {err}", file=path) from None
    found, stack = [], [schema]
    while stack:
        node = stack.pop()
        if isinstance(node, list):
            stack.extend(node)
        elif isinstance(node, dict):
            if "__loader__" in node or "__class__" in node:
                found.append((str(node.get("__loader__")),
                              f"{node.get('__module__')}.{node.get('__class__')}"))
            stack.extend(node.values())
    return found
