"""One estimator contract: every registered predictor passes scikit-learn's estimator checks,
or declares a deviation with a reason (its tags, or ``registry.expected_failed_checks`` for
scikit-learn's own estimators used as they are). The registry is enumerated, so every entry
added later is checked too."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from features.readings.errors import InputError
from models import registry

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
