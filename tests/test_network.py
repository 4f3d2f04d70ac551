"""The shallow network and its trainlm-like Levenberg-Marquardt trainer."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.base import clone
from sklearn.model_selection import KFold, cross_val_score

from models.estimators import network
from models.estimators.network import ShallowNetwork


def smooth(n=432, noise=0.0, seed=0, p=2):
    """y = sin(x1) + 0.5 x2^2 on uniform inputs in [-2, 2] (extra inputs are irrelevant)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, p))
    f = np.sin(X[:, 0]) + 0.5 * X[:, 1] ** 2
    return X, f + rng.normal(0, noise, n), f


def rmse(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)))


@pytest.fixture(scope="module")
def noisy_fit():
    X, y, f = smooth(noise=0.05)
    return ShallowNetwork(random_state=0).fit(X, y), X, y, f


def test_lm_converges_fast_on_smooth_function(noisy_fit):
    model, X, y, f = noisy_fit
    assert model.best_epoch_ < 100
    assert rmse(model.predict(X), f) < 0.1 * y.std()
    test = model.test_index_
    assert rmse(model.predict(X[test]), y[test]) < 0.15 * y.std()


def test_lm_stops_on_max_fail_and_keeps_best_validation_weights(noisy_fit):
    model, X, y, _ = noisy_fit
    val = np.asarray(model.history_["val_mse"])
    assert model.stop_reason_ == "max_fail"
    assert len(val) - 1 == model.best_epoch_ + model.max_fail
    assert val[model.best_epoch_] == val.min()
    # the returned weights are those of the best epoch, not the last
    Xv, yv = X[model.val_index_], y[model.val_index_]
    scaled_mse = np.mean(((model.predict(Xv) - yv) * model.y_gain_) ** 2)
    assert scaled_mse == pytest.approx(val.min(), rel=1e-9)
    assert scaled_mse < val[-1]


def test_split_is_dividerand_70_15_15(noisy_fit):
    model, X, *_ = noisy_fit
    parts = [model.train_index_, model.val_index_, model.test_index_]
    assert [len(p) for p in parts] == [302, 65, 65]
    assert np.array_equal(np.sort(np.concatenate(parts)), np.arange(len(X)))
    # scaling comes from the training split only: training inputs span exactly [-1, 1]
    scaled = (X[model.train_index_] - model.x_centre_) * model.x_gain_
    assert np.allclose(scaled.min(0), -1) and np.allclose(scaled.max(0), 1)


def test_mu_decreases_after_successful_steps(noisy_fit):
    model, *_ = noisy_fit
    mu = np.asarray(model.history_["mu"])
    train = np.asarray(model.history_["train_mse"])
    assert mu[0] == model.mu
    ratio = mu[1:] / mu[:-1]
    # each epoch: some failed tries (x10) then one accepted step (x0.1)
    tries = np.log10(ratio) + 1
    assert np.allclose(tries, np.round(tries)) and tries.min() >= 0
    assert np.any(np.isclose(ratio, model.mu_dec))
    # an accepted step always lowers the training error (no penalty here)
    assert np.all(np.diff(train) < 0)


def test_jacobian_matches_autograd():
    shapes = network.layer_shapes(3, (5, 4))
    theta = torch.from_numpy(network.nguyen_widrow(shapes, "tanh", np.random.default_rng(1)))
    X = torch.from_numpy(np.random.default_rng(2).uniform(-1, 1, (7, 3)))
    for activation in ("tanh", "sigmoid", "relu"):
        out, J = network.jacobian(theta, X, shapes, activation)
        assert torch.allclose(out, network.forward(theta, X, shapes, activation))
        assert torch.allclose(J, network.jacobian_autograd(theta, X, shapes, activation),
                              atol=1e-12)


def test_nguyen_widrow_rows_have_the_nw_magnitude():
    shapes = network.layer_shapes(8, (8, 8))
    theta = torch.from_numpy(network.nguyen_widrow(shapes, "tanh", np.random.default_rng(0)))
    W, b = network.unpack(theta, shapes)[0]
    # 0.7 S^(1/R) per unit-length row, stretched to tansig's active range [-2, 2]
    assert torch.allclose(torch.linalg.vector_norm(W, dim=1),
                          torch.full((8,), 2 * 0.7 * 8 ** (1 / 8), dtype=torch.float64))
    assert torch.allclose(b.abs().sort().values[-1], torch.tensor(2 * 0.7 * 8 ** (1 / 8),
                                                                  dtype=torch.float64))


def test_min_grad_stop():
    X, y, _ = smooth(n=200, noise=0.05)
    model = ShallowNetwork(min_grad=1e3, random_state=0).fit(X, y)
    assert model.stop_reason_ == "min_grad"
    assert model.history_["grad_norm"][-1] < 1e3
    assert len(model.history_["train_mse"]) == 1


def test_epochs_stop_without_validation():
    X, y, _ = smooth(n=200, noise=0.05)
    model = ShallowNetwork(epochs=7, val_fraction=0.0, random_state=0).fit(X, y)
    assert model.stop_reason_ == "epochs"
    assert len(model.val_index_) == 0
    assert len(model.history_["train_mse"]) == 8 and model.best_epoch_ == 7


def test_goal_and_mu_max_stops():
    X, y, _ = smooth(n=200, noise=0.05)
    goal = ShallowNetwork(goal=0.05, random_state=0).fit(X, y)
    assert goal.stop_reason_ == "goal" and goal.history_["train_mse"][-1] <= 0.05
    capped = ShallowNetwork(mu=1.0, mu_max=1e-3, random_state=0).fit(X, y)
    assert capped.stop_reason_ == "mu_max"


def test_adam_fits_the_same_function():
    X, y, f = smooth(noise=0.05)
    model = ShallowNetwork(trainer="adam", epochs=600, learning_rate=0.02,
                           random_state=0).fit(X, y)
    assert model.stop_reason_ in ("max_fail", "epochs")
    assert set(model.history_) == {"train_mse", "val_mse", "test_mse"}
    assert rmse(model.predict(X), f) < 0.2 * y.std()
    val = np.asarray(model.history_["val_mse"])
    assert val[model.best_epoch_] == val.min()


def test_weight_decay_shrinks_weights():
    X, y, _ = smooth(n=200, noise=0.05)
    plain = ShallowNetwork(random_state=0).fit(X, y)
    decayed = ShallowNetwork(weight_decay=1e-2, random_state=0).fit(X, y)
    assert decayed.weights_.norm() < plain.weights_.norm()


def test_sklearn_clone_params_and_cross_val_score():
    X, y, _ = smooth(n=200, noise=0.05)
    model = ShallowNetwork(hidden_sizes=(6,), epochs=50, random_state=3)
    copy = clone(model)
    assert copy.get_params() == model.get_params()
    copy.set_params(activation="sigmoid", hidden_sizes=(4, 4))
    assert copy.get_params()["hidden_sizes"] == (4, 4)
    scores = cross_val_score(model, X, y, cv=KFold(3, shuffle=True, random_state=0),
                             scoring="neg_root_mean_squared_error")
    assert scores.shape == (3,) and np.all(-scores < 0.5 * y.std())


def test_save_load_round_trip(tmp_path, monkeypatch, noisy_fit):
    model, X, *_ = noisy_fit
    path = model.save(tmp_path / "net")
    assert path.name == "network.pt"
    calls = []
    real_load = torch.load

    def spy(*args, **kwargs):
        calls.append(kwargs.get("weights_only"))
        return real_load(*args, **kwargs)

    monkeypatch.setattr(torch, "load", spy)
    loaded = ShallowNetwork.load(tmp_path / "net")
    assert calls == [True]
    assert np.array_equal(loaded.predict(X), model.predict(X))
    assert loaded.get_params() == model.get_params()
    assert loaded.history_ == model.history_ and loaded.stop_reason_ == model.stop_reason_
    assert np.array_equal(loaded.test_index_, model.test_index_)


def test_feature_names_survive_save(tmp_path):
    import pandas as pd

    X, y, _ = smooth(n=120, noise=0.05)
    frame = pd.DataFrame(X, columns=["feed_mm_min", "temperature_c"])
    model = ShallowNetwork(epochs=5, random_state=0).fit(frame, y)
    loaded = ShallowNetwork.load(model.save(tmp_path).parent)
    assert list(loaded.feature_names_in_) == ["feed_mm_min", "temperature_c"]
    assert np.array_equal(loaded.predict(frame), model.predict(frame))


def test_deterministic_with_same_seed_and_different_with_another():
    X, y, _ = smooth(n=200, noise=0.05)
    a = ShallowNetwork(random_state=5).fit(X, y).predict(X)
    b = ShallowNetwork(random_state=5).fit(X, y).predict(X)
    c = ShallowNetwork(random_state=6).fit(X, y).predict(X)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_constant_input_column_is_harmless():
    X, y, f = smooth(n=200, noise=0.05, p=3)
    X[:, 2] = 7.0
    model = ShallowNetwork(random_state=0).fit(X, y)
    assert np.all(np.isfinite(model.predict(X)))
    assert rmse(model.predict(X), f) < 0.2 * y.std()
