"""The effect-model baseline: scikit-learn's estimator checks, recovery of known lost motion,
saving without pickle."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from models.estimators.effect_model import EffectModelBaseline
from models.serving.persistence import load_estimator, save_estimator


@parametrize_with_checks([EffectModelBaseline()])
def test_sklearn_estimator_checks(estimator, check):
    check(estimator)


def lost_motion_table(seed: int = 0) -> tuple[pd.DataFrame, np.ndarray]:
    """b = 2 + 1.5 um per m/min of feed - 0.4 um/K (T - 20) + 0.6 um per 1000 h, noise 0.05."""
    rng = np.random.default_rng(seed)
    n = 300
    X = pd.DataFrame({"target": rng.uniform(0, 300, n), "feed_mm_min": rng.choice(
        [200.0, 600.0, 1200.0], n), "machine_temp_c": rng.uniform(19, 25, n),
        "operating_hours": rng.uniform(0, 4000, n), "pressure_hpa": rng.normal(1013, 5, n)})
    y = (2.0 + 1.5 * X["feed_mm_min"] / 1000 - 0.4 * (X["machine_temp_c"] - 20)
         + 0.6 * X["operating_hours"] / 1000 + rng.normal(0, 0.05, n))
    return X, y.to_numpy()


def test_terms_come_from_the_records_and_recover_the_truth():
    X, y = lost_motion_table()
    model = EffectModelBaseline().fit(X, y)
    assert model.terms_ == ["backlash", "backlash_position", "backlash_feed",
                            "backlash_temperature", "operating_hours"]
    coef = dict(zip(model.terms_, model.coef_))
    assert coef["backlash_feed"] == pytest.approx(1.5, abs=0.1)
    assert coef["backlash_temperature"] == pytest.approx(-0.4, abs=0.03)
    assert coef["operating_hours"] == pytest.approx(0.6, abs=0.05)
    assert abs(coef["backlash_position"]) < 0.1
    # numpy input with named features gives the same model; unnamed columns only a constant
    named = EffectModelBaseline(features=tuple(X.columns)).fit(X.to_numpy(), y)
    np.testing.assert_allclose(named.predict(X.to_numpy()), model.predict(X), atol=1e-9)
    unnamed = EffectModelBaseline().fit(X.to_numpy(), y)
    assert unnamed.terms_ == ["backlash"]
    np.testing.assert_allclose(unnamed.predict(X.to_numpy()), y.mean())
    with pytest.raises(ValueError, match="features"):
        EffectModelBaseline(features=("target",)).fit(X.to_numpy(), y)


def test_saves_and_loads_without_pickle(tmp_path):
    X, y = lost_motion_table(1)
    model = EffectModelBaseline().fit(X, y)
    spec = save_estimator(model, tmp_path, "estimator")
    assert spec["format"] == "json"
    loaded = load_estimator(tmp_path, spec, EffectModelBaseline())
    np.testing.assert_allclose(loaded.predict(X), model.predict(X))
