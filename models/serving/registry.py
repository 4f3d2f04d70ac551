"""Named predictors, and saving/loading a trained one without unpickling untrusted files.

One record per predictor (``PREDICTORS``, a ``Predictor`` each: name, description, how to build
it, its save format, whether it is a wear map that restarts its clock at an adjustment and
whether it forecasts a plan); the CLI's choices and help and the docs' table (``table()``) are
read from it. Every entry is a scikit-learn style estimator working on the feature table
(``features.table``), so cross-validation, permutation importance and Optuna objectives
treat the network, the physics baselines and the comparators alike.

A trained model directory holds ``model.json`` (name, features, target definition,
validation error, training input ranges, the machine axes and units it was trained on
(``scope``), data hash, and the spec and sha256 of every part),
``training_inputs.csv`` (for input-drift tests) and the fitted estimator, written and read by
``models.serving.persistence`` (its own format, plain JSON or skops; the loader's checks are described
there). ``load_model`` is the only reader of model directories.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from features.readings import schema
from features.readings.errors import InputError

MODEL_FILE = "model.json"
TRAINING_INPUTS = "training_inputs.csv"

RECOMMENDED = "wear-map"
AXIS_KEYS = schema.AXIS_KEYS  # the columns that name a machine axis


@dataclass(frozen=True)
class Predictor:
    """One predictor the product can train: the record the CLI choices, the help and the docs
    table come from.

    Attributes
    ----------
    name : str
        Registry name (``--model``, ``model=``, ``model.json``'s ``name``).
    description : str
        One line for the help and the docs.
    build : callable
        ``build(random_state) -> estimator``: an unfitted scikit-learn style estimator (imports
        only what it needs).
    save_format : str
        How ``models.serving.persistence.save_estimator`` writes it (read back by
        ``models.serving.persistence.load_estimator`` with this record's estimator as the template):
        ``json`` (plain numbers), ``torch`` (a state dict read with ``weights_only``),
        ``parts`` (a composite writing each part in its own format) or ``skops`` (allow-listed
        types only).
    wear_clock : bool
        A wear map: trained on the visits since the last mechanical adjustment of each machine
        axis (the wear clock restarts there), where a per-point model uses every row.
    forecasts : bool
        Predicts a plan of a visit not measured yet (operating hours and conditions only, no
        linear-test deviations), with a 95 % interval. Scored on the hold-out, then saved
        refit on every point: a forecast must not lose a target's or a visit's history to the
        hold-out (an axis with two visits can have a target whose points all fall in it).
    per_axis : bool
        Knows every machine axis: fitted on inputs that carry ``machine_id`` and ``axis``
        (``AXIS_KEYS``), one model per axis pooled across the fleet.
    """

    name: str
    description: str
    build: Callable[[int], object] = field(repr=False)
    save_format: str = "json"
    wear_clock: bool = False
    forecasts: bool = False
    per_axis: bool = False


def _network(**params):
    from models.estimators.network import ShallowNetwork

    return ShallowNetwork(**params)


def _baselines():
    from models.estimators import baselines

    return baselines


def _effect_model():
    from models.estimators.effect_model import EffectModelBaseline

    return EffectModelBaseline()


def _hybrid(seed: int):
    return _baselines().PhysicsHybrid(physics=_effect_model(),
                                      residual=_network(hidden_sizes=(8, 8), trainer="lm",
                                                        random_state=seed))


def _wear_map(seed: int = 0):
    from models.wear.wear_map import WearMap

    return WearMap()


def _wear_map_hybrid(seed: int):
    return _baselines().PhysicsHybrid(physics=_wear_map(),
                                      residual=_network(hidden_sizes=(8, 8), trainer="lm",
                                                        random_state=seed))


def _ensemble(seed: int):
    from models.estimators.ensemble import BootstrapEnsemble

    return BootstrapEnsemble(_network(trainer="lm", random_state=seed), n_members=5,
                             random_state=seed)


def _scaled(regressor):
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    return make_pipeline(StandardScaler(), regressor)


def _knn(seed: int):
    from sklearn.neighbors import KNeighborsRegressor

    return _scaled(KNeighborsRegressor(n_neighbors=5, weights="distance"))


def _gbr(seed: int):
    from sklearn.ensemble import GradientBoostingRegressor

    return GradientBoostingRegressor(random_state=seed)


def _ridge(seed: int):
    from sklearn.linear_model import RidgeCV

    return _scaled(RidgeCV(alphas=(0.01, 0.1, 1, 10)))


# Every predictor, in the order of the help and of ``compare``'s default list.
PREDICTORS = {p.name: p for p in (
    Predictor("wear-map", "level and wear rate along the screw (B-splines, CV) plus feed and "
              "temperature terms; forecasts the next visit with a 95 % interval (recommended)",
              _wear_map, "json", wear_clock=True, forecasts=True, per_axis=True),
    Predictor("wear-map-hybrid", "wear map plus the paper's 8-8-8-1 network on its residual",
              _wear_map_hybrid, "parts", wear_clock=True),
    Predictor("shallow-lm-ensemble", "five paper networks on bootstrap resamples: mean and a "
              "95 % interval from their spread", _ensemble, "parts"),
    Predictor("hybrid", "effect-model physics fit plus a small network on its residual",
              _hybrid, "parts"),
    Predictor("shallow-lm", "paper network 8-8-8-1 tanh, Levenberg-Marquardt like MATLAB "
              "trainlm", lambda seed: _network(trainer="lm", random_state=seed), "torch"),
    Predictor("shallow-adam", "paper network 8-8-8-1 tanh, Adam with early stopping",
              lambda seed: _network(trainer="adam", random_state=seed), "torch"),
    Predictor("effect-model", "least-squares fit of the twin's lost-motion effects",
              lambda seed: _effect_model(), "json"),
    Predictor("constant", "constant backlash (mean of the training targets)",
              lambda seed: _baselines().ConstantBacklash(), "json"),
    Predictor("linear-temperature", "backlash linear in machine temperature",
              lambda seed: _baselines().LinearInTemperature(), "json"),
    Predictor("bezier", "Bezier curve of degree 4 over position, 5 control points (least "
              "squares)", lambda seed: _baselines().BezierPosition(), "json"),
    Predictor("bspline", "B-spline of degree 2 over position, 5 coefficients (least squares)",
              lambda seed: _baselines().BSplinePosition(), "json"),
    Predictor("knn", "k-nearest-neighbour regressor on standardised inputs (distance weighted)",
              _knn, "skops"),
    Predictor("gbr", "gradient boosting regressor", _gbr, "skops"),
    Predictor("ridge", "ridge regression on standardised inputs (alpha by cross-validation)",
              _ridge, "skops"),
)}


def names() -> list[str]:
    return list(PREDICTORS)


def predictor(name: str, parameter: str = "model") -> Predictor:
    """The record of predictor ``name``; ``InputError`` naming ``parameter`` if unknown."""
    check_name(name, parameter)
    return PREDICTORS[name]


def check_name(name: str, parameter: str = "model") -> None:
    if name not in PREDICTORS:
        raise InputError(f"unknown model {name!r}; expected one of {', '.join(names())}",
                         parameter=parameter)


def make(name: str, random_state: int = 0, **params):
    """An unfitted estimator by registry name; ``params`` override its defaults."""
    estimator = predictor(name).build(random_state)
    return estimator.set_params(**params) if params else estimator


def help_text() -> str:
    """The predictors as help text: ``name: description`` for each."""
    return "; ".join(f"{p.name}: {p.description}" for p in PREDICTORS.values())


def table() -> list[dict]:
    """One row per predictor for the docs: name, description, save format, wear clock,
    forecasts a plan."""
    return [{"name": p.name, "description": p.description, "save format": p.save_format,
             "wear clock": p.wear_clock, "forecasts a plan": p.forecasts}
            for p in PREDICTORS.values()]


def predictors_table() -> str:
    """``table()`` as Markdown, for ``docs/train.md`` (filled in by ``docs/hooks.py`` as the
    site is built)."""
    rows = table()
    columns = list(rows[0])

    def cell(column: str, value) -> str:
        if column == "name":
            return f"`{value}`"
        if isinstance(value, bool):
            return "yes" if value else "no"
        return str(value).replace("*", r"\*").replace("|", r"\|")

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(c, row[c]) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def register(record: Predictor) -> Predictor:
    """Add a predictor from outside this module: ``train``, ``compare``, ``--model``'s help and
    the docs' table read it from then on (``models.serving.persistence`` saves it by its
    ``save_format``).

    Raises
    ------
    ValueError
        When a predictor of that name exists already.
    """
    if record.name in PREDICTORS:
        raise ValueError(f"predictor {record.name!r} exists already")
    PREDICTORS[record.name] = record
    return record


def unregister(name: str) -> None:
    """Remove predictor ``name`` (one added by ``register``)."""
    del PREDICTORS[predictor(name).name]


def with_axes(X, meta):
    """The inputs ``X`` with the machine axis of each row (``AXIS_KEYS`` from ``meta``, as
    text) in front: what a per-axis predictor is fitted on and predicts from."""
    import pandas as pd

    keys = [k for k in AXIS_KEYS if k in meta]
    if len(keys) < len(AXIS_KEYS):
        return X
    axes = meta[keys].astype(str).reset_index(drop=True).set_axis(X.index)
    return pd.concat([axes, X], axis=1)


def knows_axes(estimator) -> list[tuple[str, str]]:
    """The machine axes a per-axis estimator was fitted on (more than one: it needs
    ``AXIS_KEYS`` to predict); empty for every other estimator."""
    axes = getattr(estimator, "axes_", None) or []
    return list(axes) if getattr(estimator, "pooled_", False) else []


def required_inputs(estimator) -> tuple[str, ...]:
    """Named inputs without which ``estimator`` is not the model its name promises."""
    needed = getattr(estimator, "required_inputs", None)
    return tuple(needed()) if callable(needed) else ()


def check_inputs(name: str, estimator, columns, source: str = "data") -> None:
    """Refuse a feature set that lacks an input the predictor ``name`` needs."""
    missing = [c for c in required_inputs(estimator) if c not in list(columns)]
    if missing:
        raise InputError(f"predictor {name!r} needs the input {missing[0]!r}; the feature "
                         f"set {', '.join(map(str, columns))} lacks it", file=source,
                         parameter="features")


# scikit-learn estimators used as they are, with the estimator checks scikit-learn itself
# expects them to fail and its reasons (sklearn.utils._test_common.instance_generator)
THIRD_PARTY_DEVIATIONS = {
    "sklearn.pipeline.Pipeline": {
        "check_dont_overwrite_parameters":
            "Pipeline fits the estimators inside its `steps` parameter in place",
        "check_estimators_overwrite_params":
            "Pipeline fits the estimators inside its `steps` parameter in place",
    },
    "sklearn.ensemble._gb.GradientBoostingRegressor": {
        "check_sample_weight_equivalence_on_dense_data":
            "sample_weight is not equivalent to removing/repeating samples",
        "check_sample_weight_equivalence_on_sparse_data":
            "sample_weight is not equivalent to removing/repeating samples",
    },
}


def expected_failed_checks(estimator) -> dict[str, str]:
    """scikit-learn estimator checks ``estimator`` is declared to fail, with the reason."""
    from models.serving.persistence import class_name

    return dict(THIRD_PARTY_DEVIATIONS.get(class_name(type(estimator)), {}))


@dataclass
class TrainedModel:
    """A fitted estimator with what monitoring needs to know about its training."""

    name: str
    estimator: object
    feature_names_: list[str]
    target_kind: str
    validation_rmse_: float
    input_ranges_: dict[str, tuple[float, float]]
    training_inputs_: object = None  # DataFrame of the training inputs
    meta: dict = field(default_factory=dict)

    def inputs(self, X, source: str = "data"):
        """The columns of ``X`` the estimator predicts from: the features, and the machine
        axis of each row when the model knows more than one (missing ones: one error line)."""
        if not knows_axes(self.estimator):
            return X[self.feature_names_]
        missing = [k for k in AXIS_KEYS if k not in X]
        if missing:
            raise InputError(f"model {self.name!r} knows {len(knows_axes(self.estimator))} "
                             f"machine axes: the inputs need the column(s) {', '.join(missing)}"
                             " to say which axis each row is", file=source, column=missing[0])
        return X[[*AXIS_KEYS, *self.feature_names_]].astype({k: str for k in AXIS_KEYS})

    def predict(self, X):
        return self.estimator.predict(self.inputs(X))


def save_model(model: TrainedModel, directory) -> Path:
    """Write a trained model directory (see module docstring)."""
    from features.readings.fileio import atomic_path, write_json
    from models.serving.persistence import digest, save_estimator

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    spec = save_estimator(model.estimator, directory, "estimator")
    inputs = {}
    if model.training_inputs_ is not None:
        with atomic_path(directory / TRAINING_INPUTS) as tmp:
            model.training_inputs_.to_csv(tmp, index=False)
        inputs = {"training_inputs_sha256": digest(directory / TRAINING_INPUTS)}
    write_json(directory / MODEL_FILE, {
        "name": model.name, "estimator": spec,
        "features": model.feature_names_, "target_kind": model.target_kind,
        "validation_rmse_um": model.validation_rmse_,
        "input_ranges": {k: list(v) for k, v in model.input_ranges_.items()},
        **inputs, **model.meta,
    })
    return directory


def load_model(directory) -> TrainedModel:
    """Read a model directory written by ``save_model``; refuse anything unexpected.

    Checked before anything is built: ``model.json``'s keys and types, the predictor name (the
    registry builds the template whose exact classes the saved parts must have), each part's
    path (inside the directory) and sha256.
    """
    from models.serving.persistence import load_estimator

    directory = Path(directory)
    meta_path = directory / MODEL_FILE
    if not meta_path.is_file():
        raise InputError("not a trained model directory: no model.json", file=directory)
    meta = _read_meta(meta_path)
    template = make(meta["name"])
    estimator = load_estimator(directory, meta["estimator"], template, where=meta_path)
    fitted_on = getattr(estimator, "feature_names_in_", None)
    if fitted_on is not None and list(fitted_on) != list(meta["features"]):
        raise InputError("model.json key 'features' differs from the inputs the estimator was "
                         f"fitted on ({', '.join(map(str, fitted_on))})", file=meta_path)
    training = None
    if "training_inputs_sha256" in meta:
        training = _read_training_inputs(directory, meta["training_inputs_sha256"], meta_path)
    known = {"name", "estimator", "features", "target_kind", "validation_rmse_um",
             "input_ranges", "training_inputs_sha256"}
    return TrainedModel(
        meta["name"], estimator, list(meta["features"]), meta["target_kind"],
        float(meta["validation_rmse_um"]),
        {k: (float(v[0]), float(v[1])) for k, v in meta["input_ranges"].items()}, training,
        {k: v for k, v in meta.items() if k not in known})


def _read_meta(path: Path) -> dict:
    """model.json, with every key ``load_model`` uses checked for presence and type."""
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError(f"model.json is not valid JSON: {err}", file=path) from None
    if not isinstance(meta, dict):
        raise InputError("model.json must hold a JSON object", file=path)
    expected = {"name": str, "estimator": dict, "features": list, "target_kind": str,
                "validation_rmse_um": (int, float), "input_ranges": dict}
    for key, kind in expected.items():
        if key not in meta:
            raise InputError(f"model.json lacks the key {key!r}", file=path)
        if not isinstance(meta[key], kind) or isinstance(meta[key], bool):
            raise InputError(f"model.json key {key!r} has the wrong type "
                             f"({type(meta[key]).__name__})", file=path)
    if meta["name"] not in PREDICTORS:
        raise InputError(f"model.json names an unknown predictor {meta['name']!r}", file=path)
    if not meta["features"] or not all(isinstance(f, str) for f in meta["features"]):
        raise InputError("model.json key 'features' must list the input column names",
                         file=path)
    for name, bounds in meta["input_ranges"].items():
        if (not isinstance(bounds, list) or len(bounds) != 2
                or not all(isinstance(b, (int, float)) for b in bounds)):
            raise InputError(f"model.json input range of {name!r} must be [low, high]",
                             file=path)
    if not isinstance(meta.get("training_inputs_sha256", ""), str):
        raise InputError("model.json key 'training_inputs_sha256' must be text", file=path)
    if "scope" in meta:
        _check_scope(meta["scope"], path)
    return meta


def _check_scope(scope, path: Path) -> None:
    """model.json's ``scope`` (``models.serving.signature.scope_of``): the machine axes the model was
    trained on, each with the unit of its axis (``um`` linear, ``arcsec`` rotary)."""
    axes = scope.get("axes") if isinstance(scope, dict) else None
    if not isinstance(axes, list) or not axes:
        raise InputError("model.json key 'scope' must list the machine axes the model was "
                         "trained on ('axes')", file=path)
    for axis in axes:
        if (not isinstance(axis, dict) or not all(isinstance(axis.get(k), str)
                                                  for k in ("machine_id", "axis", "unit"))):
            raise InputError("model.json 'scope' axes need the text keys machine_id, axis and "
                             "unit", file=path)
        if axis["unit"] != schema.deviation_unit(axis["axis"]):
            raise InputError(f"model.json 'scope' gives axis {axis['axis']} the unit "
                             f"{axis['unit']!r}; its unit is "
                             f"{schema.deviation_unit(axis['axis'])!r}", file=path)


def _read_training_inputs(directory: Path, sha256: str, where: Path):
    import hashlib
    import io

    import pandas as pd

    from models.serving.persistence import confined

    path = confined(directory, TRAINING_INPUTS, where)
    if not path.is_file():
        raise InputError(f"model part {TRAINING_INPUTS!r} is missing", file=where)
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != sha256:
        raise InputError(f"model part {TRAINING_INPUTS!r} does not match its sha256 (changed "
                         "or damaged since it was saved)", file=where)
    try:
        return pd.read_csv(io.BytesIO(data))
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read the training inputs: {err}", file=path) from None
