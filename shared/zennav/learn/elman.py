"""Elman recurrent network with online learning on a sliding window (seed 002). The forward pass (``step``, the
predictor's) is numpy only, edge-side; the training pass (``train_pass``) is compiled by numba where it trains.

J. L. Elman, "Finding structure in time", Cognitive Science 14 (1990) 179-211. As seed 002 (eq. 6-8):
  u(k)  = f(W1 x(k) + W2 uc(k) + b1)      hidden layer, f(a) = (1 - e^-a) / (1 + e^-a) (bipolar sigmoid)
  uc(k) = u(k-1) + alpha uc(k-1)           context layer (alpha = context_gain; 0 is Elman's copy-back)
  y(k)  = W3 u(k) + b3                     linear ("purelin") output
trained by back-propagation of the squared error with the context taken as an extra input (Elman's
one-step truncation), by per-sample gradient steps over a fixed-size window of the newest samples; the
oldest sample leaves the window when a new one arrives. As seed 002 says, learning starts only once
alignment is done (set_aligned), and the network predicts only while its training error is under the
threshold. Inputs and targets are normalised with the given means/stds; the threshold is an RMSE in
normalised target units. The caller pairs each target with the features that explain it (seed 002 feeds
x(k-1) for the increment ending at k).

A network in service elsewhere (the predictor) needs only ARRAY_NAMES (weights and context), the
normalisation and the context gain: `step` is its forward pass, the one `Elman.predict` runs.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

ARRAY_NAMES = ("w1", "w2", "b1", "w3", "b3", "context")


def bipolar_sigmoid(a: np.ndarray) -> np.ndarray:
    """(1 - e^-a) / (1 + e^-a), computed as tanh(a/2); range (-1, 1), derivative (1 - f^2) / 2."""
    return np.tanh(0.5 * a)


def step(arrays: Mapping[str, np.ndarray], norm: Mapping[str, np.ndarray], x, context: np.ndarray,
         context_gain: float) -> tuple[np.ndarray, np.ndarray]:
    """One forward step: output (physical units) for input x (physical units) and the next context."""
    xn = (np.asarray(x, dtype=float) - norm["x_mean"]) / norm["x_std"]
    h = bipolar_sigmoid(arrays["w1"] @ xn + arrays["w2"] @ context + arrays["b1"])
    return (arrays["w3"] @ h + arrays["b3"]) * norm["y_std"] + norm["y_mean"], h + context_gain * context


def train_pass(w1, w2, b1, w3, b3, win_x, win_y, win_ctx, lr, gain):
    """One pass of per-sample gradient steps (lr) over the window (win_x, win_y: normalised inputs and targets, oldest
    first), in place on the weights (w1, w2, b1, w3, b3): the error of y = W3 f(W1 x + W2 uc + b1) + b3 back-propagated
    with the context uc taken as an input. The contexts are recomputed with the current weights from the oldest
    sample's stored one (win_ctx, rewritten; the next uc = f(..) + gain uc). Returns (sum of squared errors, the
    context after the newest sample). Scalar loops in a fixed order: the same floats as plain Python and compiled
    (compiled_train_pass)."""
    n_h, n_in = w1.shape
    n_out = w3.shape[0]
    ctx = win_ctx[0].copy()
    h, e, dh = np.empty(n_h), np.empty(n_out), np.empty(n_h)
    sse = 0.0
    for k in range(win_x.shape[0]):
        win_ctx[k, :] = ctx
        for i in range(n_h):
            a1, a2 = 0.0, 0.0
            for j in range(n_in):
                a1 += w1[i, j] * win_x[k, j]
            for j in range(n_h):
                a2 += w2[i, j] * ctx[j]
            h[i] = math.tanh(0.5 * (a1 + a2 + b1[i]))  # bipolar_sigmoid
        for o in range(n_out):
            y = 0.0
            for i in range(n_h):
                y += w3[o, i] * h[i]
            e[o] = y + b3[o] - win_y[k, o]
            sse += e[o] * e[o]
        for i in range(n_h):
            g = 0.0
            for o in range(n_out):
                g += w3[o, i] * e[o]
            dh[i] = g * 0.5 * (1.0 - h[i] * h[i])
        for o in range(n_out):
            for i in range(n_h):
                w3[o, i] -= lr * (e[o] * h[i])
            b3[o] -= lr * e[o]
        for i in range(n_h):
            for j in range(n_in):
                w1[i, j] -= lr * (dh[i] * win_x[k, j])
            for j in range(n_h):
                w2[i, j] -= lr * (dh[i] * ctx[j])
            b1[i] -= lr * dh[i]
        for i in range(n_h):
            ctx[i] = h[i] + gain * ctx[i]
    return sse, ctx


_compiled_pass = None


def compiled_train_pass():
    """train_pass compiled by numba (cached on disk beside this module; imported at the first training pass: the
    predictor's forward pass, ``step``, stays numpy only); NUMBA_DISABLE_JIT=1: train_pass itself."""
    global _compiled_pass
    if _compiled_pass is None:
        import numba

        _compiled_pass = numba.njit(cache=True)(train_pass)
    return _compiled_pass


class Elman:
    """Online Elman network: learn(x, y) while the reference is good, predict(x) (None if not ready)."""

    _ARRAYS = ("w1", "w2", "b1", "w3", "b3", "context", "win_x", "win_y", "win_ctx")

    def __init__(self, n_in: int, n_hidden: int, n_out: int, *, window: int = 200, lr: float = 0.01,
                 epochs: int = 1, threshold: float = 0.2, min_samples: int | None = None,
                 context_gain: float = 0.0, norm: Mapping[str, np.ndarray] | None = None, seed: int = 0):
        if window < 1 or epochs < 1:
            raise ValueError("window and epochs must be >= 1")
        self.n_in, self.n_hidden, self.n_out = n_in, n_hidden, n_out
        self.window, self.lr, self.epochs, self.threshold = window, lr, epochs, threshold
        self.min_samples = window if min_samples is None else min_samples
        self.context_gain = context_gain
        norm = norm or {}
        self.x_mean = np.asarray(norm.get("x_mean", np.zeros(n_in)), dtype=float)
        self.x_std = np.asarray(norm.get("x_std", np.ones(n_in)), dtype=float)
        self.y_mean = np.asarray(norm.get("y_mean", np.zeros(n_out)), dtype=float)
        self.y_std = np.asarray(norm.get("y_std", np.ones(n_out)), dtype=float)
        rng = np.random.default_rng(seed)

        def init(rows, cols):  # uniform +-1/sqrt(fan-in)
            return rng.uniform(-1.0, 1.0, (rows, cols)) / math.sqrt(cols)

        self.w1, self.w2, self.b1 = init(n_hidden, n_in), init(n_hidden, n_hidden), np.zeros(n_hidden)
        self.w3, self.b3 = init(n_out, n_hidden), np.zeros(n_out)
        self.context = np.zeros(n_hidden)
        self.win_x, self.win_y = np.zeros((0, n_in)), np.zeros((0, n_out))
        self.win_ctx = np.zeros((0, n_hidden))  # context each window sample was presented with
        self.aligned = False
        self.train_rmse = math.inf
        self.n_learned = 0

    def set_aligned(self, aligned: bool = True) -> None:
        """Tell the network that the INS alignment is done (learning starts) or lost (learning stops)."""
        self.aligned = aligned

    @property
    def ready(self) -> bool:
        """Aligned, the window holds min_samples, and the last training RMSE is under the threshold."""
        return self.aligned and len(self.win_x) >= self.min_samples and self.train_rmse <= self.threshold

    def learn(self, x, y) -> float | None:
        """Add (x, y) (physical units) as the newest window sample and train on the window.

        Returns the training RMSE (normalised units), or None before alignment (nothing is stored then).
        """
        if not self.aligned:
            return None
        xn = (np.asarray(x, dtype=float) - self.x_mean) / self.x_std
        yn = (np.asarray(y, dtype=float) - self.y_mean) / self.y_std
        self.win_x = np.vstack([self.win_x, xn])[-self.window:]
        self.win_y = np.vstack([self.win_y, yn])[-self.window:]
        self.win_ctx = np.vstack([self.win_ctx, self.context])[-self.window:]
        for _ in range(self.epochs):
            self.train_rmse = self._train_pass()
        self.n_learned += 1
        return self.train_rmse

    def _train_pass(self) -> float:
        """One pass of per-sample gradient steps from the oldest window sample to the newest (train_pass, compiled)."""
        sse, self.context = compiled_train_pass()(self.w1, self.w2, self.b1, self.w3, self.b3, self.win_x,
                                                  self.win_y, self.win_ctx, self.lr, self.context_gain)
        return math.sqrt(sse / (len(self.win_x) * self.n_out))

    def predict(self, x) -> np.ndarray | None:
        """Output (physical units) for input x, advancing the context; None while not ready."""
        if not self.ready:
            return None
        y, self.context = step(self.arrays(), self.norm(), x, self.context, self.context_gain)
        return y

    def renormalize(self, norm: Mapping[str, np.ndarray]) -> None:
        """Take new input/output means and stds (physical units) without changing what the network computes:
        the first layer and the output layer are rescaled and shifted to match, and the stored window is
        re-expressed in the new units (hidden activations and context are unchanged)."""
        x_mean, x_std = np.asarray(norm["x_mean"], dtype=float), np.asarray(norm["x_std"], dtype=float)
        y_mean, y_std = np.asarray(norm["y_mean"], dtype=float), np.asarray(norm["y_std"], dtype=float)
        self.b1 = self.b1 + self.w1 @ ((x_mean - self.x_mean) / self.x_std)
        self.w1 = self.w1 * (x_std / self.x_std)[None, :]
        self.b3 = (self.b3 * self.y_std + self.y_mean - y_mean) / y_std
        self.w3 = self.w3 * (self.y_std / y_std)[:, None]
        self.win_x = (self.win_x * self.x_std + self.x_mean - x_mean) / x_std
        self.win_y = (self.win_y * self.y_std + self.y_mean - y_mean) / y_std
        self.x_mean, self.x_std, self.y_mean, self.y_std = x_mean, x_std, y_mean, y_std

    def arrays(self) -> dict[str, np.ndarray]:
        """Weights and context (ARRAY_NAMES), the live arrays (not copies)."""
        return {k: getattr(self, k) for k in ARRAY_NAMES}

    def norm(self) -> dict[str, np.ndarray]:
        """x_mean, x_std, y_mean, y_std."""
        return dict(x_mean=self.x_mean, x_std=self.x_std, y_mean=self.y_mean, y_std=self.y_std)

    def get_state(self) -> dict:
        """Weights, context, window and counters as copies (numpy arrays and Python scalars)."""
        state = {k: getattr(self, k).copy() for k in self._ARRAYS}
        state.update(aligned=self.aligned, train_rmse=self.train_rmse, n_learned=self.n_learned)
        return state

    def set_state(self, state: Mapping) -> None:
        """Restore a get_state() dict taken from a network of the same sizes."""
        for k in self._ARRAYS:
            v, cur = np.array(state[k], dtype=float), getattr(self, k)
            if k.startswith("win_"):
                ok = v.ndim == 2 and v.shape[1] == cur.shape[1] and len(v) <= self.window
            else:
                ok = v.shape == cur.shape
            if not ok:
                raise ValueError(f"state {k} has shape {v.shape}, network has {cur.shape}")
            setattr(self, k, v)
        self.aligned, self.train_rmse = bool(state["aligned"]), float(state["train_rmse"])
        self.n_learned = int(state["n_learned"])
