"""Regularised linear least squares for the ANFIS consequents (trainer side; imports torch).

In Jang's hybrid rule the output is linear in the consequent parameters once the premises are fixed, so
the forward pass solves them by least squares (J.-S. R. Jang, "ANFIS: adaptive-network-based fuzzy inference
system", IEEE Trans. SMC 23(3) 1993, sec. IV.A). Here with a Tikhonov (ridge) term, which keeps the solve
well posed when a rule hardly fires (A. N. Tikhonov, 1963; Hoerl & Kennard, Technometrics 12, 1970).
"""
from __future__ import annotations

import numpy as np
import torch


def ridge_lstsq(A, Y, ridge: float = 0.0):
    """argmin_X |A X - Y|_F^2 + ridge |X|_F^2 for A (N, P) and Y (N,) or (N, M).

    ridge == 0: the minimum-norm least-squares solution, as numpy.linalg.lstsq (SVD: LAPACK gelsd on the
    CPU, the pseudo-inverse on a GPU). ridge > 0: the normal equations (A'A + ridge I) X = A'Y by Cholesky,
    falling back to the SVD of the stacked system [A; sqrt(ridge) I] if the factorisation fails.
    Takes numpy arrays or torch tensors and returns the same kind.
    """
    if ridge < 0.0:
        raise ValueError("ridge must be >= 0")
    as_numpy = isinstance(A, np.ndarray)
    A_t, Y_t = torch.as_tensor(A), torch.as_tensor(Y)
    Y2 = Y_t[:, None] if Y_t.ndim == 1 else Y_t
    if ridge == 0.0:
        X = _min_norm_lstsq(A_t, Y2)
    else:
        eye = torch.eye(A_t.shape[1], dtype=A_t.dtype, device=A_t.device)
        L, info = torch.linalg.cholesky_ex(A_t.T @ A_t + ridge * eye)
        if int(info) == 0:
            X = torch.cholesky_solve(A_t.T @ Y2, L)
        else:
            zeros = torch.zeros(A_t.shape[1], Y2.shape[1], dtype=Y2.dtype, device=Y2.device)
            X = _min_norm_lstsq(torch.cat([A_t, ridge**0.5 * eye]), torch.cat([Y2, zeros]))
    X = X[:, 0] if Y_t.ndim == 1 else X
    return X.numpy() if as_numpy else X


def _min_norm_lstsq(A: torch.Tensor, Y: torch.Tensor) -> torch.Tensor:
    if A.device.type == "cpu":
        return torch.linalg.lstsq(A, Y, driver="gelsd").solution
    return torch.linalg.pinv(A) @ Y
