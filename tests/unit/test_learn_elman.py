"""Elman network: online window learning, gating, state round trip."""
import numpy as np
import pytest

from zennav.learn.elman import Elman, bipolar_sigmoid, compiled_train_pass, train_pass


def _sequence(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = 0.1 * np.arange(n)
    x = np.stack([np.sin(t), np.cos(0.5 * t), 0.1 * rng.normal(size=n)], axis=1)
    y = (0.5 * np.sin(t - 0.3) + 0.2 * np.cos(0.5 * t) ** 2)[:, None] * 4.0 + 1.0
    return x, y


def _net(**kw):
    args = dict(window=60, lr=0.05, threshold=0.15, norm=dict(y_mean=np.array([1.0]), y_std=np.array([4.0])),
                seed=3)
    args.update(kw)
    return Elman(3, 8, 1, **args)


def test_bipolar_sigmoid():
    a = np.linspace(-30, 30, 101)
    np.testing.assert_allclose(bipolar_sigmoid(a), (1 - np.exp(-a)) / (1 + np.exp(-a)), rtol=1e-12, atol=1e-15)


def test_learns_only_after_alignment_and_predicts_only_under_threshold():
    x, y = _sequence()
    net = _net()
    assert net.learn(x[0], y[0]) is None and len(net.win_x) == 0  # not aligned: nothing stored
    assert net.predict(x[0]) is None
    net.set_aligned()
    ready = []
    for i in range(300):
        net.learn(x[i], y[i])
        ready.append(net.ready)
    assert len(net.win_x) == net.window == 60  # fixed-size window of the newest samples
    np.testing.assert_allclose(net.win_y[-1], (y[299] - 1.0) / 4.0)
    assert not any(ready[:59])  # min_samples defaults to the window size
    assert net.ready and net.train_rmse <= 0.15
    pred = np.array([net.predict(x[i]) for i in range(300, 340)])
    assert np.sqrt(np.mean((pred - y[300:340]) ** 2)) < 0.15 * 4.0

    strict = _net(threshold=1e-6)  # never reaches its threshold: never predicts
    strict.set_aligned()
    for i in range(100):
        strict.learn(x[i], y[i])
    assert not strict.ready and strict.predict(x[100]) is None


def test_not_ready_before_the_window_fills():
    x, y = _sequence()
    net = _net(min_samples=30)
    net.set_aligned()
    for i in range(29):
        net.learn(x[i], y[i])
    assert not net.ready
    net.set_aligned(False)
    assert net.learn(x[29], y[29]) is None and not net.ready


def test_state_round_trip_gives_identical_outputs():
    x, y = _sequence()
    net = _net()
    net.set_aligned()
    for i in range(150):
        net.learn(x[i], y[i])
    state = net.get_state()
    clone = _net(seed=99)  # different initial weights, overwritten by the state
    clone.set_state(state)
    outputs = []
    for other in (net, clone):
        out = [other.learn(x[i], y[i]) for i in range(150, 170)]
        out += [other.predict(x[i]) for i in range(170, 190)]
        out += [other.learn(x[i], y[i]) for i in range(190, 195)]
        outputs.append(out)
    assert outputs[0][20] is not None
    for a, b in zip(*outputs):
        np.testing.assert_array_equal(a, b)
    state["win_x"][:] = 0.0  # get_state returns copies
    assert np.any(net.win_x != 0.0)
    with pytest.raises(ValueError):
        Elman(3, 5, 1).set_state(net.get_state())


def test_renormalize_keeps_what_the_network_computes():
    """New input/output means and stds: the same outputs for the same inputs and context, and the stored window
    in the new units (one more learning step from there gives the same result as in the old units only if the
    window was re-expressed, so it is checked directly)."""
    rng = np.random.default_rng(5)
    net = Elman(4, 6, 2, window=50, min_samples=20, threshold=10.0, seed=0)
    net.set_aligned()
    xs, ys = rng.normal(1.0, 3.0, (30, 4)), rng.normal(0.0, 1.0, (30, 2))
    for x, y in zip(xs, ys):
        net.learn(x, y)
    state = net.get_state()
    probe = rng.normal(1.0, 3.0, (5, 4))
    before = [net.predict(x) for x in probe]
    net.set_state(state)
    new = dict(x_mean=np.array([0.5, -1.0, 2.0, 0.0]), x_std=np.array([2.0, 0.5, 4.0, 1.0]),
               y_mean=np.array([1.0, -1.0]), y_std=np.array([3.0, 0.5]))
    net.renormalize(new)
    np.testing.assert_allclose([net.predict(x) for x in probe], before, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(net.win_x, (xs - new["x_mean"]) / new["x_std"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(net.win_y, (ys - new["y_mean"]) / new["y_std"], rtol=1e-12, atol=1e-12)


def test_training_pass_compiled_gives_the_python_floats_and_the_matrix_form():
    """train_pass compiled by numba = train_pass as Python, bit for bit (weights, stored contexts, error sum,
    context); and the matrix form of the same steps (numpy) to rounding."""
    rng = np.random.default_rng(4)
    n_in, n_h, n_out, n = 5, 6, 2, 40
    arrays = [rng.normal(size=s) for s in ((n_h, n_in), (n_h, n_h), (n_h,), (n_out, n_h), (n_out,))]
    window = [rng.normal(size=(n, n_in)), rng.normal(size=(n, n_out)), 0.1 * rng.normal(size=(n, n_h))]
    runs = []
    for fn in (train_pass, compiled_train_pass()):
        a, w = [x.copy() for x in arrays], [x.copy() for x in window]
        for _ in range(3):
            sse, ctx = fn(*a, *w, 0.05, 0.3)
        runs.append((sse, ctx, a, w))
    (sse, ctx, a, w), other = runs
    assert sse == other[0] and np.array_equal(ctx, other[1])
    assert all(np.array_equal(x, y) for x, y in zip(a + w, other[2] + other[3]))
    w1, w2, b1, w3, b3 = [x.copy() for x in arrays]  # the matrix form, one pass
    x, y, c = (v.copy() for v in window)
    ref_ctx, ref_sse = c[0].copy(), 0.0
    for k in range(n):
        c[k] = ref_ctx
        h = bipolar_sigmoid(w1 @ x[k] + w2 @ ref_ctx + b1)
        e = w3 @ h + b3 - y[k]
        ref_sse += float(e @ e)
        dh = (w3.T @ e) * 0.5 * (1.0 - h * h)
        w3 -= 0.05 * np.outer(e, h)
        b3 -= 0.05 * e
        w1 -= 0.05 * np.outer(dh, x[k])
        w2 -= 0.05 * np.outer(dh, ref_ctx)
        b1 -= 0.05 * dh
        ref_ctx = h + 0.3 * ref_ctx
    a, w = [v.copy() for v in arrays], [v.copy() for v in window]
    sse, ctx = train_pass(*a, *w, 0.05, 0.3)
    np.testing.assert_allclose(sse, ref_sse, rtol=1e-12)
    np.testing.assert_allclose(ctx, ref_ctx, rtol=1e-12, atol=1e-14)
    for got, want in zip(a + w, [w1, w2, b1, w3, b3, x, y, c]):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
