"""Zero-phase 4th-order Butterworth low-pass along axis 0: the same floats as
``scipy.signal.filtfilt(*scipy.signal.butter(4, wn), x, axis=0)`` (odd extension of 3 * 5 samples at each end, the
step response's steady state as initial conditions, transposed direct form II run forward, then backward), without
importing scipy.signal: that import (about 1.2 s) was most of a replay's start (issue 17).

The coefficients of the cutoffs a loader uses are written out (``COEFFICIENTS``, from scipy.signal.butter;
tests/unit/test_butterworth.py ties them and the filter's output to scipy's). The recursion runs in Python floats,
one column at a time, in scipy's order of operations (``_lfilter``): the same rounding, bit for bit.
Zero phase means non-causal: for post-processing only.
"""
from __future__ import annotations

import numpy as np

ORDER = 4
PAD = 3 * (ORDER + 1)  # samples of odd extension at each end (scipy filtfilt's default padlen)
# normalized cutoff wn (cutoff / Nyquist) -> (b, a) of scipy.signal.butter(4, wn)
COEFFICIENTS = {
    0.2: ((0.004824343357716228, 0.019297373430864913, 0.02894606014629737, 0.019297373430864913,
           0.004824343357716228),
          (1.0, -2.369513007182038, 2.313988414415881, -1.054665405878568, 0.18737949236818502)),
    0.1: ((0.00041659920440659937, 0.0016663968176263975, 0.002499595226439596, 0.0016663968176263975,
           0.00041659920440659937),
          (1.0, -3.180638548874719, 3.8611943489942133, -2.112155355110969, 0.43826514226197977)),
}


def steady_state(b, a) -> np.ndarray:
    """The filter's state after a long run of ones (scipy.signal.lfilter_zi, a[0] = 1): zi = A zi + B, A the
    companion matrix of a transposed, B = b[1:] - a[1:] b[0]."""
    b, a = np.asarray(b, dtype=float), np.asarray(a, dtype=float)
    n = len(a) - 1
    companion = np.zeros((n, n))
    companion[0] = -a[1:]
    companion[np.arange(1, n), np.arange(n - 1)] = 1.0
    return np.linalg.solve(np.eye(n) - companion.T, b[1:] - a[1:] * b[0])


def _lfilter(b, a, x: list[float], z: list[float]) -> list[float]:
    """Transposed direct form II of a 4th-order filter (a[0] = 1) over x from state z, as scipy's C loop computes
    it: y = z0 + b0 x, z_i = z_(i+1) + x b_(i+1) - y a_(i+1)."""
    b0, b1, b2, b3, b4 = b
    _, a1, a2, a3, a4 = a
    z0, z1, z2, z3 = z
    out: list[float] = []
    put = out.append
    for v in x:
        y = z0 + b0 * v
        z0 = z1 + v * b1 - y * a1
        z1 = z2 + v * b2 - y * a2
        z2 = z3 + v * b3 - y * a3
        z3 = v * b4 - y * a4
        put(y)
    return out


def lowpass(x: np.ndarray, wn: float) -> np.ndarray:
    """x (N,) or (N, k) low-passed forward and backward at the normalized cutoff wn (a key of COEFFICIENTS);
    ValueError for another cutoff or N <= PAD (as scipy's filtfilt)."""
    if wn not in COEFFICIENTS:
        raise ValueError(f"no Butterworth coefficients for wn={wn!r} (add scipy.signal.butter(4, wn) to COEFFICIENTS)")
    x = np.asarray(x, dtype=float)
    if len(x) <= PAD:
        raise ValueError(f"the low-pass needs more than {PAD} samples, got {len(x)}")
    b, a = COEFFICIENTS[wn]
    zi = steady_state(b, a)
    cols = x.reshape(len(x), -1)
    ext = np.concatenate([2.0 * cols[0:1] - cols[PAD:0:-1], cols, 2.0 * cols[-1:] - cols[-2:-(PAD + 2):-1]])
    out = np.empty_like(ext)
    for j, col in enumerate(ext.T.tolist()):
        fwd = _lfilter(b, a, col, (zi * col[0]).tolist())
        fwd.reverse()
        back = _lfilter(b, a, fwd, (zi * fwd[0]).tolist())
        back.reverse()
        out[:, j] = back
    return out[PAD:-PAD].reshape(x.shape)
