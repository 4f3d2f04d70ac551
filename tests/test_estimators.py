"""One estimator contract: every registered predictor passes scikit-learn's estimator checks,
or declares a deviation with a reason (its tags, or ``registry.expected_failed_checks`` for
scikit-learn's own estimators used as they are). The registry is enumerated, so every entry
added later is checked too."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.utils._param_validation import InvalidParameterError
from sklearn.utils.estimator_checks import check_param_validation, parametrize_with_checks

from features.readings.errors import InputError
from models.serving import registry

# few epochs and trees keep the checks fast; Adam then needs a larger step to fit at all
FAST = {"epochs": 30, "learning_rate": 0.1, "n_estimators": 10}


def fast(estimator):
    """``estimator`` with every (nested) epoch count and Adam step set to ``FAST``."""
    params = estimator.get_params(deep=True)
    return estimator.set_params(**{key: FAST[key.rpartition("__")[2]] for key in params
                                   if key.rpartition("__")[2] in FAST})


ESTIMATORS = [fast(registry.make(name)) for name in registry.names()]


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """The checks fit hundreds of tiny networks: one thread each, no oversubscription."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@parametrize_with_checks(ESTIMATORS, expected_failed_checks=registry.expected_failed_checks)
def test_sklearn_estimator_checks(estimator, check):
    check(estimator)


def test_every_deviation_has_a_reason():
    for estimator in ESTIMATORS:
        for check, reason in registry.expected_failed_checks(estimator).items():
            assert check.startswith("check_") and len(reason) > 20, (estimator, check)


def _axis_points(seed=0, n=60):
    """Backlash that grows along the axis and with machine temperature, with the columns in
    the feature table's order and one unrelated input."""
    rng = np.random.default_rng(seed)
    X = pd.DataFrame({"target": rng.uniform(0, 400, n), "feed_mm_min": rng.choice([200, 500], n),
                      "machine_temp_c": rng.uniform(18, 26, n)})
    y = 2.0 + 0.004 * X["target"] + 0.3 * (X["machine_temp_c"] - 20)
    return X, y.to_numpy()


@pytest.mark.parametrize("name", ["linear-temperature", "bezier", "bspline", "constant",
                                  "effect-model", "hybrid"])
def test_numpy_with_features_equals_the_named_frame(name):
    """The ``features`` convention: a numpy array with names fits what the DataFrame fits."""
    X, y = _axis_points()
    frame = fast(registry.make(name)).fit(X, y)
    named = fast(registry.make(name))
    if "features" in named.get_params():
        named.set_params(features=tuple(X.columns))
    named.fit(X.to_numpy(), y)
    assert named.predict(X.to_numpy()) == pytest.approx(frame.predict(X), abs=1e-9)


def test_physics_terms_use_their_named_inputs_and_are_left_out_when_unnamed():
    X, y = _axis_points()
    model = registry.make("linear-temperature").fit(X, y - 0.004 * X["target"])
    assert model.slope_um_per_k_ == pytest.approx(0.3, abs=1e-9)
    unnamed = registry.make("linear-temperature").fit(X.to_numpy(), y)
    assert unnamed.temperature_column_ is None and unnamed.slope_um_per_k_ == 0.0
    assert unnamed.predict(X.to_numpy()) == pytest.approx(np.full(len(y), y.mean()))


def test_feature_names_that_do_not_fit_the_columns_are_refused():
    X, y = _axis_points()
    with pytest.raises(ValueError, match="features must name each"):
        registry.make("bezier", features=("target",)).fit(X.to_numpy(), y)


@pytest.mark.parametrize("name, needs", [("linear-temperature", "machine_temp_c"),
                                         ("bezier", "target"), ("bspline", "target")])
def test_required_inputs_are_declared(name, needs):
    assert needs in registry.required_inputs(registry.make(name))
    with pytest.raises(InputError, match=f"needs the input {needs!r}"):
        registry.check_inputs(name, registry.make(name), ["feed_mm_min", "dwell_s"])


# ----------------------------------------------------------------------------- parameters

@pytest.mark.parametrize("name", registry.names())
def test_parameters_are_validated_declaratively(name):
    """Every predictor declares a constraint per parameter and enforces it at ``fit`` with a
    ValueError naming the parameter (scikit-learn's own check of ``_parameter_constraints``)."""
    estimator = registry.make(name)
    check_param_validation(type(estimator).__name__, estimator)


@pytest.mark.parametrize("name, params, parameter", [
    ("wear-map", {"alpha": -1}, "alpha"),
    ("wear-map", {"level": 2.0}, "level"),
    ("wear-map", {"max_control": 0}, "max_control"),
    ("wear-map", {"n_control": "everywhere"}, "n_control"),
    ("shallow-lm", {"mu": -1e-3}, "mu"),
    ("shallow-adam", {"batch_size": 0}, "batch_size"),
    ("shallow-lm", {"hidden_sizes": (8, 0)}, "hidden_sizes"),
    ("shallow-lm", {"activation": "softmax"}, "activation"),
    ("shallow-lm-ensemble", {"n_members": 1}, "n_members"),
    ("shallow-lm-ensemble", {"estimator__mu": -1.0}, "mu"),
    ("hybrid", {"residual__mu": -1.0}, "mu"),
    ("wear-map-hybrid", {"physics__level": 2.0}, "level"),
    ("effect-model", {"n_centers": 0}, "n_centers"),
    ("bspline", {"n_control": 0}, "n_control"),
    ("bezier", {"degree": 0}, "degree"),
    ("linear-temperature", {"temperature": 20}, "temperature"),
])
def test_a_bad_parameter_is_a_clear_error_at_fit(name, params, parameter):
    X, y = _axis_points()
    estimator = fast(registry.make(name, **params))
    with pytest.raises(InvalidParameterError, match=f"The '{parameter}' parameter of") as caught:
        estimator.fit(X, y)
    assert isinstance(caught.value, ValueError)


# ----------------------------------------------------------------------------- one JSON format

def _hours_points(seed=0, n=60):
    X, y = _axis_points(seed, n)
    X["operating_hours"] = np.repeat([0.0, 500.0, 1000.0, 1500.0], n // 4)
    return X, y + 0.002 * X["operating_hours"].to_numpy()


@pytest.mark.parametrize("name, file_name", [("wear-map", "wear_map.json"),
                                             ("hybrid", "hybrid.json"),
                                             ("shallow-lm-ensemble", "ensemble.json")])
def test_own_json_state_is_written_atomically_and_read_back(tmp_path, name, file_name):
    from models.serving import persistence

    X, y = _hours_points()
    model = fast(registry.make(name)).fit(X, y)
    spec = persistence.save_estimator(model, tmp_path, "estimator")
    assert (tmp_path / "estimator" / file_name).is_file()
    assert sorted(p.name for p in tmp_path.rglob("*.tmp*")) == []
    back = persistence.load_estimator(tmp_path, spec, registry.make(name))
    np.testing.assert_allclose(back.predict(X), model.predict(X))
    assert list(back.feature_names_in_) == list(X.columns)


@pytest.mark.parametrize("name, file_name, key", [("wear-map", "wear_map.json", "coef_"),
                                                  ("wear-map", "wear_map.json", "n_features_in"),
                                                  ("hybrid", "hybrid.json", "residual"),
                                                  ("shallow-lm-ensemble", "ensemble.json",
                                                   "members")])
def test_a_missing_key_is_an_input_error_naming_the_file(tmp_path, name, file_name, key):
    import json

    X, y = _hours_points()
    folder = tmp_path / "estimator"
    fast(registry.make(name)).fit(X, y).save(folder)
    state = json.loads((folder / file_name).read_text())
    del state[key]
    (folder / file_name).write_text(json.dumps(state))
    template = registry.make(name)
    load = (type(template).load if name == "wear-map"
            else lambda d: type(template).load(d, template=template))
    with pytest.raises(InputError, match=f"broken {file_name}: lacks the key {key!r}") as caught:
        load(folder)
    assert caught.value.file.endswith(file_name)


@pytest.mark.parametrize("name, file_name, change", [
    ("wear-map", "wear_map.json", lambda s: s["params"].update(level=2.0)),
    ("shallow-lm-ensemble", "ensemble.json", lambda s: s["params"].update(n_members=0)),
])
def test_saved_parameters_are_validated_on_load(tmp_path, name, file_name, change):
    import json

    X, y = _hours_points()
    folder = tmp_path / "estimator"
    fast(registry.make(name)).fit(X, y).save(folder)
    state = json.loads((folder / file_name).read_text())
    change(state)
    (folder / file_name).write_text(json.dumps(state))
    template = registry.make(name)
    with pytest.raises(InputError, match="saved parameters are invalid"):
        if name == "wear-map":
            type(template).load(folder)
        else:
            type(template).load(folder, template=template)
