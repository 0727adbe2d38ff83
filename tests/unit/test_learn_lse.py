"""Least-squares step for the ANFIS consequents."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")
torch.set_num_threads(1)

from zennav.learn.lse import ridge_lstsq  # noqa: E402


@pytest.mark.parametrize("rank_deficient", [False, True])
@pytest.mark.parametrize("n_out", [None, 3])
def test_equals_numpy_lstsq_without_regulariser(rank_deficient, n_out):
    rng = np.random.default_rng(0)
    A = rng.normal(size=(60, 8))
    if rank_deficient:
        A[:, 7] = A[:, 0] + 2.0 * A[:, 1]  # minimum-norm solution required
    Y = rng.normal(size=60 if n_out is None else (60, n_out))
    expected = np.linalg.lstsq(A, Y, rcond=None)[0]
    got = ridge_lstsq(A, Y)
    assert isinstance(got, np.ndarray) and got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)
    got_t = ridge_lstsq(torch.from_numpy(A), torch.from_numpy(Y))
    assert isinstance(got_t, torch.Tensor)
    np.testing.assert_allclose(got_t.numpy(), expected, rtol=1e-9, atol=1e-12)


def test_ridge_solution_matches_the_closed_form_and_shrinks():
    rng = np.random.default_rng(1)
    A, Y = rng.normal(size=(40, 6)), rng.normal(size=(40, 2))
    lam = 3.0
    expected = np.linalg.solve(A.T @ A + lam * np.eye(6), A.T @ Y)
    got = ridge_lstsq(A, Y, lam)
    np.testing.assert_allclose(got, expected, rtol=1e-10)
    # the same minimiser as the stacked system [A; sqrt(lam) I] solved by numpy's lstsq
    stacked = np.linalg.lstsq(np.vstack([A, np.sqrt(lam) * np.eye(6)]), np.vstack([Y, np.zeros((6, 2))]),
                              rcond=None)[0]
    np.testing.assert_allclose(got, stacked, rtol=1e-10)
    assert np.linalg.norm(got) < np.linalg.norm(ridge_lstsq(A, Y))
    with pytest.raises(ValueError):
        ridge_lstsq(A, Y, -1.0)
