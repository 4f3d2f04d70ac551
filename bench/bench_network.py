"""Levenberg-Marquardt epoch time of the torch network against a compact numpy reference with an
analytic Jacobian (same data, same initial weights, same run), the torch analytic Jacobian
against ``torch.func.jacrev``, and the time of a full 8-8-8-1 fit on 432 samples.

Goals: torch LM epoch <= 2x the numpy reference; full fit under 0.3 s.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg

from bench import size

N_SAMPLES, N_INPUTS, EPOCHS, REPEATS = size(432, 100), 8, size(100, 3), size(3, 1)
JACOBIANS = size(100, 2)  # Jacobians timed in a row
RATIO_GOAL, FIT_GOAL_S = 2.0, 0.3


def data(seed: int = 0, noise: float = 0.05):
    """A smooth function of 8 inputs (two of them matter) plus noise."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (N_SAMPLES, N_INPUTS))
    return X, np.sin(X[:, 0]) + 0.5 * X[:, 1] ** 2 + rng.normal(0, noise, N_SAMPLES)


# ---------------------------------------------------------------- numpy reference (8-8-8-1 tanh)

def np_unpack(theta, shapes):
    layers, start = [], 0
    for o, i in shapes:
        layers.append((theta[start:start + o * i].reshape(o, i),
                       theta[start + o * i:start + o * i + o]))
        start += o * i + o
    return layers


def np_forward(theta, X, shapes):
    layers = np_unpack(theta, shapes)
    outputs = [X]
    for W, b in layers[:-1]:
        outputs.append(np.tanh(outputs[-1] @ W.T + b))
    W, b = layers[-1]
    return (outputs[-1] @ W.T + b)[:, 0], outputs, layers


def np_jacobian(theta, X, shapes):
    """Output and analytic Jacobian d y / d theta (N, P) of a tanh MLP with linear output."""
    out, outputs, layers = np_forward(theta, X, shapes)
    N, blocks, delta = len(X), [], np.ones((len(X), 1))
    for k in range(len(layers) - 1, -1, -1):
        blocks += [delta, (delta[:, :, None] * outputs[k][:, None, :]).reshape(N, -1)]
        if k:
            delta = (delta @ layers[k][0]) * (1 - outputs[k] ** 2)
    return out, np.concatenate(blocks[::-1], axis=1)


def np_lm(theta, parts, shapes, epochs, mu=1e-3, mu_dec=0.1, mu_inc=10, mu_max=1e10):
    """Plain trainlm loop (no validation stop) recording train/val/test MSE each epoch."""
    X, y = parts["train"]
    eye = np.eye(theta.size)
    mse = {k: [] for k in parts}

    def sse(t):
        e = np_forward(t, X, shapes)[0] - y
        return e @ e

    perf = sse(theta)
    for _ in range(epochs + 1):
        out, J = np_jacobian(theta, X, shapes)
        grad = J.T @ (out - y)
        for name, (Xp, yp) in parts.items():
            mse[name].append(np.mean((np_forward(theta, Xp, shapes)[0] - yp) ** 2))
        JJ = J.T @ J
        while mu <= mu_max:
            try:
                factor = scipy.linalg.cho_factor(JJ + mu * eye)
            except np.linalg.LinAlgError:
                mu *= mu_inc
                continue
            candidate = theta - scipy.linalg.cho_solve(factor, grad)
            trial = sse(candidate)
            if trial < perf:
                theta, perf, mu = candidate, trial, max(mu * mu_dec, 1e-20)
                break
            mu *= mu_inc
    return theta, mse


# ---------------------------------------------------------------- measurements

def _best_of(fn, repeats=REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    import threadpoolctl
    import torch

    from models.estimators import network

    X, y = data()
    fixed = {"trainer": "lm", "epochs": EPOCHS, "min_grad": 0.0, "max_fail": EPOCHS + 1,
             "random_state": 0}
    model = network.ShallowNetwork(**fixed).fit(X, y)
    epochs_run = len(model.history_["train_mse"])
    t_torch = _best_of(lambda: network.ShallowNetwork(**fixed).fit(X, y)) / epochs_run

    # the same split, scaling and initial weights for the numpy reference
    Xs = (X - model.x_centre_) * model.x_gain_
    ys = (y - model.y_centre_) * model.y_gain_
    parts = {k: (Xs[getattr(model, f"{k}_index_")], ys[getattr(model, f"{k}_index_")])
             for k in ("train", "val", "test")}
    theta0 = network.nguyen_widrow(model.shapes_, "tanh", np.random.default_rng(0))
    ref = {}

    def run_numpy():
        ref.update(zip(("theta", "mse"), np_lm(theta0, parts, model.shapes_, epochs_run - 1)))

    # small matrices: multi-threaded BLAS can be far slower than one thread; compare with the
    # reference at its faster setting
    t_numpy_default = _best_of(run_numpy) / epochs_run
    with threadpoolctl.threadpool_limits(1, "blas"):
        t_numpy_1 = _best_of(run_numpy) / epochs_run
    t_numpy = min(t_numpy_default, t_numpy_1)
    agree = np.max(np.abs(np.array(ref["mse"]["train"]) - model.history_["train_mse"]))

    theta = torch.from_numpy(theta0)
    Xt = torch.from_numpy(parts["train"][0])
    t_jac = _best_of(lambda: [network.jacobian(theta, Xt, model.shapes_, "tanh")
                              for _ in range(JACOBIANS)]) / JACOBIANS
    t_jacrev = _best_of(lambda: [network.jacobian_autograd(theta, Xt, model.shapes_, "tanh")
                                 for _ in range(JACOBIANS)]) / JACOBIANS

    t_fit = _best_of(lambda: network.ShallowNetwork(random_state=0).fit(X, y))
    paper = network.ShallowNetwork(random_state=0).fit(X, y)

    rows = [
        ("torch threads", f"{torch.get_num_threads()}", ""),
        ("LM epoch, torch [ms]", f"{1e3 * t_torch:.3f}", f"{epochs_run} epochs"),
        ("LM epoch, numpy reference [ms]", f"{1e3 * t_numpy_default:.3f}", "default BLAS threads"),
        ("LM epoch, numpy reference [ms]", f"{1e3 * t_numpy_1:.3f}", "1 BLAS thread"),
        ("ratio torch / numpy (faster)", f"{t_torch / t_numpy:.2f}", f"goal <= {RATIO_GOAL}"),
        ("max |train MSE torch - numpy|", f"{agree:.1e}", "same trajectory"),
        ("Jacobian analytic [ms]", f"{1e3 * t_jac:.3f}", f"{Xt.shape[0]} x {theta.numel()}"),
        ("Jacobian torch.func.jacrev [ms]", f"{1e3 * t_jacrev:.3f}",
         f"{t_jacrev / t_jac:.1f}x slower"),
        ("full 8-8-8-1 fit [s]", f"{t_fit:.3f}",
         (f"goal < {FIT_GOAL_S}; {paper.stop_reason_}, best epoch {paper.best_epoch_} of "
          f"{len(paper.history_['train_mse']) - 1}")),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>10}  {note}")


if __name__ == "__main__":
    main()
