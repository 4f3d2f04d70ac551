"""The paper's shallow feed-forward network (8-8-8-1, tanh) with a Levenberg-Marquardt trainer
that follows MATLAB ``trainlm``, and an Adam alternative.

What mirrors MATLAB (``feedforwardnet`` + ``train`` defaults, [BacklashNN], Sec. 3-4):

- ``mapminmax``: inputs and target mapped to [-1, 1] with the training split's range only.
- ``dividerand``: seeded random train/validation/test split (70/15/15) inside ``fit``; the test
  part is never trained on and only recorded in ``history_``.
- ``initnw``: Nguyen-Widrow initial weights for the hidden layers, uniform [-1, 1] for the
  linear output layer.
- ``trainlm``: each epoch the Jacobian J of the training residuals e with respect to all weights,
  ``dx = -(J^T J + mu I)^-1 J^T e``; accepted (``mu *= mu_dec``) if the performance drops,
  otherwise ``mu *= mu_inc`` and retried until ``mu > mu_max``. Stops on ``goal``, ``mu_max``,
  ``min_grad`` (on ||J^T e||), ``epochs`` or ``max_fail`` validation failures in a row, and
  keeps the weights of the best validation epoch.

The Jacobian is computed analytically (one backward sweep of per-sample deltas, vectorised over
samples); ``jacobian_autograd`` computes the same matrix with ``torch.func`` and is used to check
it. All arithmetic is float64 on the CPU; torch's thread count is left to the caller.

Reference: M. T. Hagan, M. B. Menhaj, "Training feedforward networks with the Marquardt
algorithm", IEEE Trans. Neural Networks 5(6), 1994; D. Nguyen, B. Widrow, "Improving the
learning speed of 2-layer neural networks by choosing initial values of the adaptive weights",
IJCNN 1990; MATLAB Deep Learning Toolbox ``trainlm``, ``initnw``, ``dividerand``, ``mapminmax``.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context
from sklearn.utils._param_validation import Interval, InvalidParameterError, StrOptions
from sklearn.utils.validation import check_is_fitted, validate_data

from features.readings.fileio import atomic_path

DTYPE = torch.float64
FILE_NAME = "network.pt"
STOP_REASONS = ("max_fail", "min_grad", "mu_max", "epochs", "goal")
MU_MIN = 1e-20                         # trainlm's floor on mu
ADAM_PATIENCE_FACTOR = 10              # Adam patience = 10 * max_fail epochs (noisier steps)

# activation, its derivative expressed through the activation's output a, and the half-width
# and centre of its active input range (MATLAB ``activeInputRange``) used by Nguyen-Widrow
_ACTIVATIONS = {
    "tanh": (torch.tanh, lambda a: 1.0 - a * a, 2.0, 0.0),
    "sigmoid": (torch.sigmoid, lambda a: a * (1.0 - a), 4.0, 0.0),
    "relu": (torch.relu, lambda a: (a > 0).to(a.dtype), 1.0, 0.0),
}


# ----------------------------------------------------------------------------- scaling

def minmax_fit(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre and gain of MATLAB ``mapminmax`` to [-1, 1] per column.

    Parameters
    ----------
    values : (N, p) array [any unit]

    Returns
    -------
    centre, gain : (p,) arrays with ``scaled = (x - centre) * gain``,
        ``centre = (max + min) / 2``, ``gain = 2 / (max - min)``; a constant column gets
        gain 1, so it maps to 0 (no division by zero).
    """
    low, high = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
    span = high - low
    gain = np.where(span > 0, 2.0 / np.where(span > 0, span, 1.0), 1.0)
    return (high + low) / 2.0, gain


# ----------------------------------------------------------------------------- split

def divide_rand(n: int, val_fraction: float, test_fraction: float,
                random_state: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded random train/validation/test indices like MATLAB ``dividerand``.

    ``n_val = round(val_fraction n)``, ``n_test = round(test_fraction n)``, the rest trains
    (at least one sample). Indices are sorted within each part.
    """
    if not (0 <= val_fraction < 1 and 0 <= test_fraction < 1 and val_fraction + test_fraction < 1):
        raise ValueError("val_fraction and test_fraction must be in [0, 1) and sum below 1")
    order = np.random.default_rng(random_state).permutation(n)
    n_val = min(round(val_fraction * n), max(n - 1, 0))
    n_test = min(round(test_fraction * n), max(n - 1 - n_val, 0))
    n_train = n - n_val - n_test
    return (np.sort(order[:n_train]), np.sort(order[n_train:n_train + n_val]),
            np.sort(order[n_train + n_val:]))


# ----------------------------------------------------------------------------- layers

def layer_shapes(n_inputs: int, hidden_sizes) -> list[tuple[int, int]]:
    """(out, in) of each weight matrix, output layer last."""
    sizes = [n_inputs, *hidden_sizes, 1]
    return list(zip(sizes[1:], sizes[:-1]))


def n_weights(shapes) -> int:
    return sum(o * i + o for o, i in shapes)


def unpack(theta: torch.Tensor, shapes) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Views (W [out, in], b [out]) of the flat weight vector, layer by layer."""
    layers, start = [], 0
    for o, i in shapes:
        W = theta[start:start + o * i].view(o, i)
        b = theta[start + o * i:start + o * i + o]
        layers.append((W, b))
        start += o * i + o
    return layers


def nguyen_widrow(shapes, activation: str, rng: np.random.Generator) -> np.ndarray:
    """Initial flat weight vector like MATLAB ``initnw`` for inputs already in [-1, 1].

    Hidden layer with S neurons and R inputs: rows of W uniform in [-1, 1] normalised to unit
    length and scaled by ``0.7 S^(1/R)``; biases ``0.7 S^(1/R) linspace(-1, 1, S) sign(W[:, 0])``;
    both then stretched to the activation's active input range (tanh [-2, 2]). The linear
    output layer gets uniform [-1, 1] weights and bias (MATLAB ``rands``), as ``initnw`` does for
    a transfer function with an infinite active range.
    """
    half, centre = _ACTIVATIONS[activation][2:]
    parts = []
    for k, (S, R) in enumerate(shapes):
        if k == len(shapes) - 1:
            parts += [rng.uniform(-1, 1, S * R), rng.uniform(-1, 1, S)]
            continue
        magnitude = 0.7 * S ** (1.0 / R)
        W = rng.uniform(-1, 1, (S, R))
        W = magnitude * W / np.linalg.norm(W, axis=1, keepdims=True)
        b = magnitude * np.linspace(-1, 1, S) * np.sign(W[:, 0]) if S > 1 else np.zeros(1)
        parts += [(W * half).ravel(), b * half + centre]
    return np.concatenate(parts)


def forward(theta: torch.Tensor, X: torch.Tensor, shapes, activation: str,
            keep: bool = False):
    """Network output (N,) for scaled inputs X (N, p); with ``keep`` also each layer's output."""
    f = _ACTIVATIONS[activation][0]
    layers = unpack(theta, shapes)
    a, outputs = X, [X]
    for W, b in layers[:-1]:
        a = f(torch.addmm(b, a, W.T))
        outputs.append(a)
    W, b = layers[-1]
    out = torch.addmm(b, a, W.T)[:, 0]
    return (out, outputs) if keep else out


def jacobian(theta: torch.Tensor, X: torch.Tensor, shapes, activation: str):
    """Output (N,) and its Jacobian J (N, n_weights) with respect to the flat weights.

    Per-sample backpropagation, vectorised over samples: ``delta_L = 1``,
    ``dy/dW_l = delta_l a_(l-1)^T``, ``dy/db_l = delta_l``,
    ``delta_(l-1) = (delta_l W_l) * f'(a_(l-1))`` with f' written through the layer output.
    """
    derivative = _ACTIVATIONS[activation][1]
    out, outputs = forward(theta, X, shapes, activation, keep=True)
    layers = unpack(theta, shapes)
    N = X.shape[0]
    blocks = []
    delta = torch.ones((N, 1), dtype=theta.dtype)
    for k in range(len(layers) - 1, -1, -1):
        a_prev = outputs[k]
        blocks.append(delta)                                            # biases
        blocks.append((delta[:, :, None] * a_prev[:, None, :]).reshape(N, -1))  # weights
        if k:
            delta = (delta @ layers[k][0]) * derivative(a_prev)
    return out, torch.cat(blocks[::-1], dim=1)


def jacobian_autograd(theta: torch.Tensor, X: torch.Tensor, shapes, activation: str):
    """The same Jacobian as ``jacobian`` by ``torch.func.jacrev`` (slower; for checking)."""
    return torch.func.jacrev(lambda t: forward(t, X, shapes, activation))(theta)


# ----------------------------------------------------------------------------- estimator

class ShallowNetwork(RegressorMixin, BaseEstimator):
    """Feed-forward regressor: scaled inputs -> hidden layers -> one linear output.

    Parameters
    ----------
    hidden_sizes : tuple of int
        Neurons per hidden layer; (8, 8) gives the paper's 8-8-8-1 net for 8 inputs.
    activation : {"tanh", "relu", "sigmoid"}
        Hidden-layer transfer function (MATLAB tansig / poslin / logsig).
    trainer : {"lm", "adam"}
        Levenberg-Marquardt like MATLAB ``trainlm``, or full/mini-batch Adam.
    epochs : int
        Maximum epochs (trainlm ``epochs``).
    mu, mu_dec, mu_inc, mu_max : float
        Marquardt damping: start, factor after a successful step, factor after a failed try,
        the value above which training stops.
    max_fail : int
        Validation failures in a row before stopping (Adam waits 10 x ``max_fail`` epochs).
    min_grad : float
        Stop when ||J^T e|| (training residuals in scaled units) falls below it.
    goal : float
        Stop when the training performance (scaled MSE + penalty) is at or below it.
    weight_decay : float
        L2 penalty ``weight_decay * sum(w^2)`` over all weights and biases, added to the scaled
        training MSE (both trainers).
    learning_rate : float
        Adam step size.
    batch_size : int or None
        Adam mini-batch size; None uses the whole training split.
    val_fraction, test_fraction : float
        ``dividerand`` fractions; ``val_fraction=0`` disables early stopping.
    random_state : int
        Seed of the split, the initial weights and Adam's batch order.

    Attributes
    ----------
    history_ : dict of lists
        Per epoch (epoch 0 = initial weights): ``train_mse``, ``val_mse``, ``test_mse`` in
        scaled target units ([-1, 1] range), ``mu`` (LM), ``grad_norm`` (LM).
    stop_reason_ : str, one of STOP_REASONS
    best_epoch_ : int
        Epoch whose weights are kept (best validation epoch, or the last epoch without a
        validation split).
    train_index_, val_index_, test_index_ : arrays of row positions of the ``fit`` input.
    """

    _parameter_constraints: ClassVar[dict] = {
        "hidden_sizes": ["array-like"],
        "activation": [StrOptions(set(_ACTIVATIONS))],
        "trainer": [StrOptions({"lm", "adam"})],
        "epochs": [Interval(Integral, 0, None, closed="left")],
        "mu": [Interval(Real, 0, None, closed="neither")],
        "mu_dec": [Interval(Real, 0, 1, closed="neither")],
        "mu_inc": [Interval(Real, 1, None, closed="neither")],
        "mu_max": [Interval(Real, 0, None, closed="neither")],
        "max_fail": [Interval(Integral, 1, None, closed="left")],
        "min_grad": [Interval(Real, 0, None, closed="left")],
        "goal": [Interval(Real, 0, None, closed="left")],
        "weight_decay": [Interval(Real, 0, None, closed="left")],
        "learning_rate": [Interval(Real, 0, None, closed="neither")],
        "batch_size": [None, Interval(Integral, 1, None, closed="left")],
        "val_fraction": [Interval(Real, 0, 1, closed="left")],
        "test_fraction": [Interval(Real, 0, 1, closed="left")],
        "random_state": [None, Interval(Integral, 0, None, closed="left")],
    }

    def __init__(self, hidden_sizes=(8, 8), activation="tanh", trainer="lm", epochs=1000,
                 mu=1e-3, mu_dec=0.1, mu_inc=10, mu_max=1e10, max_fail=6, min_grad=1e-7,
                 goal=0.0, weight_decay=0.0, learning_rate=1e-2, batch_size=None,
                 val_fraction=0.15, test_fraction=0.15, random_state=0):
        self.hidden_sizes = hidden_sizes
        self.activation = activation
        self.trainer = trainer
        self.epochs = epochs
        self.mu = mu
        self.mu_dec = mu_dec
        self.mu_inc = mu_inc
        self.mu_max = mu_max
        self.max_fail = max_fail
        self.min_grad = min_grad
        self.goal = goal
        self.weight_decay = weight_decay
        self.learning_rate = learning_rate
        self.batch_size = batch_size
        self.val_fraction = val_fraction
        self.test_fraction = test_fraction
        self.random_state = random_state

    # -- fitting ------------------------------------------------------------------------------

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y):
        """Split, scale on the training part, initialise and train."""
        if isinstance(self.hidden_sizes, str) or not all(
                isinstance(h, Integral) and h >= 1 for h in self.hidden_sizes):
            raise InvalidParameterError("The 'hidden_sizes' parameter of ShallowNetwork must "
                                        "list positive integers (neurons per hidden layer). "
                                        f"Got {self.hidden_sizes!r} instead.")
        X, y = validate_data(self, X, y, dtype=np.float64, y_numeric=True)
        self.train_index_, self.val_index_, self.test_index_ = divide_rand(
            len(y), self.val_fraction, self.test_fraction, self.random_state)
        self.x_centre_, self.x_gain_ = minmax_fit(X[self.train_index_])
        y_centre, y_gain = minmax_fit(y[self.train_index_, None])
        self.y_centre_, self.y_gain_ = float(y_centre[0]), float(y_gain[0])
        self.shapes_ = layer_shapes(X.shape[1], tuple(int(h) for h in self.hidden_sizes))

        Xs = torch.from_numpy((X - self.x_centre_) * self.x_gain_)
        ys = torch.from_numpy((y - self.y_centre_) * self.y_gain_)
        parts = {name: (Xs[idx], ys[idx]) for name, idx in
                 (("train", self.train_index_), ("val", self.val_index_),
                  ("test", self.test_index_))}
        rng = np.random.default_rng(self.random_state)
        theta = torch.from_numpy(nguyen_widrow(self.shapes_, self.activation, rng))
        train = self._train_lm if self.trainer == "lm" else self._train_adam
        self.weights_ = train(theta, parts, rng)
        return self

    def _mse(self, theta, part) -> float:
        X, y = part
        if not len(y):
            return math.nan
        return float(torch.mean((forward(theta, X, self.shapes_, self.activation) - y) ** 2))

    def _record(self, history, theta, parts, train_mse=None, **extra) -> float:
        for name in ("train", "val", "test"):
            known = train_mse if name == "train" and train_mse is not None else None
            history[f"{name}_mse"].append(known if known is not None
                                          else self._mse(theta, parts[name]))
        for key, value in extra.items():
            history[key].append(float(value))
        return history["val_mse"][-1]

    def _train_lm(self, theta, parts, rng):
        """MATLAB ``trainlm``: damped Gauss-Newton steps with validation stopping."""
        X, y = parts["train"]
        N, P = X.shape[0], theta.numel()
        decay = float(self.weight_decay) * N        # penalty on the sum of squares, see docs
        eye = torch.eye(P, dtype=DTYPE)
        history = {k: [] for k in ("train_mse", "val_mse", "test_mse", "mu", "grad_norm")}
        check = len(parts["val"][1]) > 0
        mu, best_val, fails, best, self.best_epoch_ = float(self.mu), math.inf, 0, theta, 0

        def perf_of(t):        # sum of squared residuals + N * penalty
            e = forward(t, X, self.shapes_, self.activation) - y
            return float(e @ e + decay * (t @ t))

        perf = perf_of(theta)
        for epoch in range(int(self.epochs) + 1):
            out, J = jacobian(theta, X, self.shapes_, self.activation)
            e = out - y
            grad = J.T @ e + decay * theta
            grad_norm = float(torch.linalg.vector_norm(grad))
            val = self._record(history, theta, parts, float(e @ e) / N, mu=mu,
                               grad_norm=grad_norm)
            if check and val < best_val:
                best_val, fails, best, self.best_epoch_ = val, 0, theta, epoch
            elif check and val > best_val:
                fails += 1
            if not check:
                best, self.best_epoch_ = theta, epoch
            reason = self._lm_stop(perf / N, mu, grad_norm, epoch, fails)
            if reason:
                break
            JJ = J.T @ J + decay * eye
            while mu <= self.mu_max:
                chol, info = torch.linalg.cholesky_ex(JJ + mu * eye)
                if not int(info):
                    candidate = theta - torch.cholesky_solve(grad[:, None], chol)[:, 0]
                    trial = perf_of(candidate)
                    if trial < perf:
                        theta, perf = candidate, trial
                        mu = max(mu * self.mu_dec, MU_MIN)
                        break
                mu *= self.mu_inc
        self.stop_reason_, self.history_ = reason, history
        return best

    def _lm_stop(self, perf, mu, grad_norm, epoch, fails) -> str:
        """trainlm's stopping tests, in its order."""
        if perf <= self.goal:
            return "goal"
        if mu > self.mu_max:
            return "mu_max"
        if grad_norm < self.min_grad:
            return "min_grad"
        if epoch >= self.epochs:
            return "epochs"
        if fails >= self.max_fail:
            return "max_fail"
        return ""

    def _train_adam(self, theta, parts, rng):
        """Adam on scaled MSE + penalty, early stopping after 10 x max_fail failing epochs."""
        X, y = parts["train"]
        theta = theta.clone().requires_grad_(True)
        optimiser = torch.optim.Adam([theta], lr=float(self.learning_rate))
        history = {k: [] for k in ("train_mse", "val_mse", "test_mse")}
        check = len(parts["val"][1]) > 0
        patience = ADAM_PATIENCE_FACTOR * int(self.max_fail)
        batch = int(self.batch_size or len(y))
        best_val, fails, best, self.best_epoch_ = math.inf, 0, theta.detach().clone(), 0
        reason = "epochs"
        for epoch in range(int(self.epochs) + 1):
            with torch.no_grad():
                val = self._record(history, theta, parts)
            if check and val < best_val:
                best_val, fails, best, self.best_epoch_ = val, 0, theta.detach().clone(), epoch
            elif check:
                fails += 1
            if not check:
                best, self.best_epoch_ = theta.detach().clone(), epoch
            penalty = self.weight_decay * float(theta.detach() @ theta.detach())
            if history["train_mse"][-1] + penalty <= self.goal:
                reason = "goal"
                break
            if check and fails >= patience:
                reason = "max_fail"
                break
            if epoch == int(self.epochs):
                break
            order = torch.from_numpy(rng.permutation(len(y))) if batch < len(y) else None
            for start in range(0, len(y), batch):
                rows = order[start:start + batch] if order is not None else slice(None)
                optimiser.zero_grad()
                e = forward(theta, X[rows], self.shapes_, self.activation) - y[rows]
                loss = torch.mean(e * e) + self.weight_decay * (theta @ theta)
                loss.backward()
                optimiser.step()
        self.stop_reason_, self.history_ = reason, history
        return best.detach()

    # -- prediction ----------------------------------------------------------------------------

    def predict(self, X) -> np.ndarray:
        """Predicted target [target unit] for each row of X."""
        check_is_fitted(self, "weights_")
        X = validate_data(self, X, dtype=np.float64, reset=False)
        Xs = torch.from_numpy((X - self.x_centre_) * self.x_gain_)
        with torch.no_grad():
            out = forward(self.weights_, Xs, self.shapes_, self.activation).numpy()
        return out / self.y_gain_ + self.y_centre_

    # -- persistence ---------------------------------------------------------------------------

    def save(self, directory) -> Path:
        """Write ``network.pt`` (tensors and JSON-safe values only) into ``directory``."""
        check_is_fitted(self, "weights_")
        path = Path(directory) / FILE_NAME
        params = {k: (list(v) if isinstance(v, tuple) else v)
                  for k, v in self.get_params().items()}
        state = {
            "params": params,
            "weights": self.weights_.clone(),
            "x_centre": torch.from_numpy(np.asarray(self.x_centre_, float)),
            "x_gain": torch.from_numpy(np.asarray(self.x_gain_, float)),
            "y_centre": self.y_centre_, "y_gain": self.y_gain_,
            "n_features_in": int(self.n_features_in_),
            "feature_names_in": [str(c) for c in getattr(self, "feature_names_in_", [])],
            "history": {k: [float(x) for x in v] for k, v in self.history_.items()},
            "stop_reason": self.stop_reason_, "best_epoch": int(self.best_epoch_),
            "split": {k: torch.from_numpy(np.asarray(getattr(self, f"{k}_index_"), np.int64))
                      for k in ("train", "val", "test")},
        }
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
        return path

    @classmethod
    def load(cls, directory) -> ShallowNetwork:
        """Rebuild a fitted network from ``save``'s file (``torch.load(weights_only=True)``)."""
        state = torch.load(Path(directory) / FILE_NAME, weights_only=True)
        params = dict(state["params"])
        params["hidden_sizes"] = tuple(int(h) for h in params["hidden_sizes"])
        if params.get("activation") not in _ACTIVATIONS:
            raise ValueError(f"unknown activation {params.get('activation')!r}")
        model = cls(**params)
        model.weights_ = state["weights"].to(DTYPE)
        model.x_centre_ = state["x_centre"].numpy()
        model.x_gain_ = state["x_gain"].numpy()
        model.y_centre_, model.y_gain_ = float(state["y_centre"]), float(state["y_gain"])
        model.n_features_in_ = int(state["n_features_in"])
        if state["feature_names_in"]:
            model.feature_names_in_ = np.asarray(state["feature_names_in"], dtype=object)
        model.shapes_ = layer_shapes(model.n_features_in_, params["hidden_sizes"])
        if model.weights_.ndim != 1 or model.weights_.numel() != n_weights(model.shapes_):
            raise ValueError("the weights do not fit the layer sizes")
        if model.x_centre_.shape != (model.n_features_in_,) or model.x_gain_.shape != (
                model.n_features_in_,):
            raise ValueError("the input scaling does not fit the number of inputs")
        model.history_ = {k: list(v) for k, v in state["history"].items()}
        model.stop_reason_, model.best_epoch_ = state["stop_reason"], int(state["best_epoch"])
        for k, v in state["split"].items():
            setattr(model, f"{k}_index_", v.numpy())
        return model
