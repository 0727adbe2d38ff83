"""ANFIS: numpy predictor vs torch model, rule bases, hybrid and comparison trainers."""
import numpy as np
import pytest

from zennav.learn import anfis_numpy as an
from zennav.learn import paramset

torch = pytest.importorskip("torch")
torch.set_num_threads(1)

from zennav.learn.anfis_torch import (  # noqa: E402
    METHODS,
    TorchAnfis,
    TrainConfig,
    _projected_grad,
    epoch_stepper,
    fit_anfis,
    fit_anfis_sigma,
    select_epochs,
    train,
)
from zennav.learn.lse import ridge_lstsq  # noqa: E402
from zennav.learn.pso import PSOConfig  # noqa: E402
from zennav.learn.sigma import answer_lag, answer_sigma  # noqa: E402


def _sinc2d(n=11):
    g = np.linspace(-10.0, 10.0, n)
    x = np.array([(a, b) for a in g for b in g])
    return x, np.sinc(x[:, 0] / np.pi) * np.sinc(x[:, 1] / np.pi)


def _random_model(n_in=5, n_rules=6, n_out=2, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(300, n_in))
    arrays = an.cluster_rulebase(x, n_rules, seed=seed)
    arrays["b"] = rng.uniform(0.3, 4.0, size=arrays["b"].shape)  # slopes below and above 1/2
    arrays["consequents"] = rng.normal(size=(n_rules, n_in + 1, n_out))
    return x, arrays


def test_bell_membership_matches_the_textbook_formula():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 3))
    a, b, c = rng.uniform(0.5, 2, (3, 4)), rng.uniform(0.5, 3, (3, 4)), rng.normal(size=(3, 4))
    x[0, 1] = c[1, 2]  # exactly at a centre
    mu = 1.0 / (1.0 + np.abs((x[:, :, None] - c) / a) ** (2.0 * b))
    np.testing.assert_allclose(np.exp(an.log_bell(x, a, b, c)), mu, rtol=1e-13, atol=1e-300)


def test_firing_equals_the_normalised_product_of_memberships():
    x, arrays = _random_model(n_in=3, n_rules=4)
    mu = np.exp(an.log_bell(x, arrays["a"], arrays["b"], arrays["c"]))
    rules = arrays["rules"]
    w = np.stack([np.prod([mu[:, j, rules[r, j]] for j in range(3)], axis=0) for r in range(4)], axis=1)
    wbar = an.normalized_firing(x, arrays["a"], arrays["b"], arrays["c"], arrays["rules"])
    np.testing.assert_allclose(wbar, w / w.sum(axis=1, keepdims=True), rtol=1e-12)


def test_numpy_predictor_equals_torch_forward():
    x, arrays = _random_model()
    x[3] = arrays["c"][:, 2]  # a sample exactly on a rule centre
    model = TorchAnfis(arrays)
    y_torch = model.forward(x).numpy()
    y_numpy = an.forward(model.to_arrays(), x)
    assert np.max(np.abs(y_numpy - y_torch)) <= 1e-6
    np.testing.assert_allclose(y_numpy, y_torch, rtol=1e-12, atol=1e-12)  # in fact to rounding


def test_torch_gradient_is_finite_at_a_membership_centre():
    x, arrays = _random_model(n_in=2, n_rules=3, n_out=1)
    x[0] = arrays["c"][:, 0]
    model = TorchAnfis(arrays)
    p = model.p.clone().requires_grad_(True)
    model.forward(x, p=p).sum().backward()
    assert torch.isfinite(p.grad).all()


def test_far_inputs_give_finite_output():
    _, arrays = _random_model(n_in=10, n_rules=8, n_out=1)
    y = an.forward(arrays, np.full((2, 10), 1e3))
    assert np.all(np.isfinite(y))


def test_rule_bases():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(500, 10))
    rb = an.cluster_rulebase(x, 12, seed=4)
    assert rb["rules"].shape == (12, 10) and rb["a"].shape == (10, 12)
    assert np.all(rb["a"] >= 0.1)
    rb2 = an.cluster_rulebase(x, 12, seed=4)
    assert all(np.array_equal(rb[k], rb2[k]) for k in rb)  # seeded
    with pytest.raises(ValueError, match="cluster_rulebase"):
        an.grid_rulebase(x, 2)  # 2**10 rules
    g = an.grid_rulebase(x[:, :2], 3)
    assert g["rules"].shape == (9, 2) and len({tuple(r) for r in g["rules"]}) == 9
    np.testing.assert_allclose(g["c"][:, [0, -1]], np.stack([x[:, :2].min(0), x[:, :2].max(0)], axis=1))


@pytest.mark.parametrize("projected", [True, False])
def test_hybrid_epochs_never_raise_the_regularised_loss(projected):
    x, y = _sinc2d()
    xn, yn = (x - x.mean(0)) / x.std(0), ((y - y.mean()) / y.std())[:, None]
    model = TorchAnfis(an.grid_rulebase(xn, 4), n_out=1)
    cfg = TrainConfig(cg_iters=5, cg_projected=projected)
    xt, yt = model.tensor(xn), model.tensor(yn)
    step = epoch_stepper(model, xt, yt, cfg)

    def loss():  # J = MSE + ridge |theta|^2 / m: the LSE minimises it exactly, every CG step lowers it
        with torch.no_grad():
            mse = float(((model.forward(xt) - yt) ** 2).mean())
        return mse + cfg.ridge * float((model.theta**2).sum()) / yt.shape[1], mse

    history = []
    for _ in range(40):
        step()
        history.append(loss())
    j = np.array([h[0] for h in history])
    assert np.all(np.diff(j) <= 1e-10 * j[:-1])
    assert history[-1][1] < 0.1  # MSE; 1 (the variance of yn) for the initial zero consequents


def test_projected_premise_gradient_matches_finite_differences():
    x, arrays = _random_model(n_in=3, n_rules=4, n_out=2, seed=1)
    y = np.random.default_rng(2).normal(size=(len(x), 2))
    model = TorchAnfis(arrays)
    xt, yt = model.tensor(x), model.tensor(y)
    f, g = _projected_grad(model, xt, yt, model.p, 1e-3)
    d = torch.as_tensor(np.random.default_rng(3).normal(size=g.shape), dtype=g.dtype)
    h = 1e-6
    fd = (float(_projected_grad(model, xt, yt, model.p + h * d, 1e-3)[0])
          - float(_projected_grad(model, xt, yt, model.p - h * d, 1e-3)[0])) / (2 * h)
    assert fd == pytest.approx(float(g @ d), rel=1e-6)
    # J(p) is the least-squares minimum: the fixed-consequents loss at the LSE solution, plus the ridge term
    theta = ridge_lstsq(model.design(xt, model.p), yt, 1e-3 * len(x))
    mse = float(((model.design(xt, model.p) @ theta - yt) ** 2).mean())
    assert float(f) == pytest.approx(mse + 1e-3 * float((theta**2).sum()) / 2, rel=1e-12)


def test_epoch_stepper_is_the_epoch_that_train_runs():
    x, y = _sinc2d(7)
    xn, yn = (x - x.mean(0)) / x.std(0), ((y - y.mean()) / y.std())[:, None]
    models = [TorchAnfis(an.grid_rulebase(xn, 3), n_out=1) for _ in range(2)]
    cfg = TrainConfig(max_epochs=3, tol=0.0)
    train(models[0], xn, yn, cfg)
    step = epoch_stepper(models[1], models[1].tensor(xn), models[1].tensor(yn), cfg)
    for _ in range(3):
        step()
    torch.testing.assert_close(models[0].p, models[1].p, rtol=0.0, atol=0.0)
    torch.testing.assert_close(models[0].theta, models[1].theta, rtol=0.0, atol=0.0)
    with pytest.raises(ValueError):
        epoch_stepper(models[1], models[1].tensor(xn), models[1].tensor(yn), TrainConfig(method="sgd"))


@pytest.mark.parametrize("method", METHODS)
def test_every_method_learns_sinc(method):
    x, y = _sinc2d()
    cfg = TrainConfig(method=method, max_epochs=15, tol=0.0, pso=PSOConfig(n_particles=8), batch_size=32,
                      adam_lr=0.05)
    fit = fit_anfis(x, y, n_mf=3, config=cfg, device="cpu")
    rmse = [h["rmse"] for h in fit.train.history]
    assert rmse[-1] < 0.9 * rmse[0]
    assert fit.metrics["method"] == method and fit.metrics["epochs"] == 15


def test_stopping_rules():
    x, y = _sinc2d(7)
    xn, yn = (x - x.mean(0)) / x.std(0), (y - y.mean()) / y.std()

    def fresh():
        return TorchAnfis(an.grid_rulebase(xn, 3), n_out=1)

    assert train(fresh(), xn, yn, TrainConfig(goal_rmse=0.9, max_epochs=50)).stop_reason == "goal"
    res = train(fresh(), xn, yn, TrainConfig(method="hybrid_gd", gd_step=1e-9, tol=1e-3, patience=2,
                                             max_epochs=50))
    assert res.stop_reason == "tol" and res.epochs < 10
    assert train(fresh(), xn, yn, TrainConfig(tol=0.0, max_epochs=3)).epochs == 3
    with pytest.raises(ValueError):
        train(fresh(), xn, yn, TrainConfig(method="sgd"))


def test_fit_to_paramset_to_numpy_prediction():
    rng = np.random.default_rng(5)
    x = rng.uniform(-1.0, 1.0, size=(400, 4)) * [1.0, 10.0, 0.1, 5.0]
    y = np.stack([np.sin(x[:, 0]) + 0.1 * x[:, 1], x[:, 2] * x[:, 3]], axis=1) * 30.0
    cfg = TrainConfig(max_epochs=10)
    fit = fit_anfis(x[:300], y[:300], n_rules=6, config=cfg, x_val=x[300:], y_val=y[300:], device="cpu")
    msg = paramset.build("anfis-test", 1, fit.arrays, fit.norm, fit.metrics)
    ps = paramset.validate(paramset.decode(paramset.encode(msg)), live_version=0, n_in=4, n_out=2)
    y_hat = an.predict(ps.arrays, ps.norm, x[300:])
    np.testing.assert_allclose(np.sqrt(np.mean((y_hat - y[300:]) ** 2, axis=0)), ps.metrics["val_rmse"],
                               rtol=1e-9)
    assert np.all(np.array(ps.metrics["val_rmse"]) < y.std(axis=0))
    single = an.predict(ps.arrays, ps.norm, x[300])  # one sample, as the edge calls it
    assert single.shape == (2,)
    np.testing.assert_allclose(single, y_hat[0], rtol=1e-12)


def test_sigma_is_the_held_out_error_when_the_fit_interpolates():
    """fit_anfis_sigma: the 1-sigma comes from the newest quarter's residuals of a fit on the rest (answer_sigma),
    at least the training RMSE; with many rules on few noisy samples the training RMSE understates it. An output
    the ANFIS has no skill on (a constant plus noise) is answered by its mean, with the mean's held-out 1-sigma."""
    rng = np.random.default_rng(8)
    x = rng.uniform(-2.0, 2.0, size=(120, 3))
    y = np.stack([np.sin(x[:, 0]) + x[:, 1], np.full(120, 0.5), x[:, 2] ** 2], axis=1) + rng.normal(0, 0.3, (120, 3))
    cfg = TrainConfig(max_epochs=5)
    fit = fit_anfis_sigma(x, y, max_rules=12, config=cfg, device="cpu")
    assert len(fit.arrays["rules"]) == 7  # 120 samples, 3 inputs: 120 // 16
    first = fit_anfis(x[:90], y[:90], n_rules=7, config=cfg, device="cpu")
    residuals, baseline = an.predict(first.arrays, first.norm, x[90:]) - y[90:], y[:90].mean(axis=0) - y[90:]
    assert fit.metrics["skill"] == [1, 0, 1]  # the ANFIS fits the noise of the constant output
    sigma, rho = answer_sigma(np.where([True, False, True], residuals, baseline))
    np.testing.assert_allclose(fit.metrics["holdout_rmse"], np.sqrt(np.mean(residuals**2, axis=0)), rtol=1e-12)
    np.testing.assert_allclose(fit.metrics["baseline_rmse"], np.sqrt(np.mean(baseline**2, axis=0)), rtol=1e-12)
    np.testing.assert_allclose(fit.metrics["holdout_rho"], rho, rtol=1e-12)
    np.testing.assert_allclose(fit.metrics["sigma"], np.maximum(sigma, fit.metrics["train_rmse"]), rtol=1e-12)
    answers = an.predict(fit.arrays, fit.norm, x)
    np.testing.assert_allclose(answers[:, 1], y[:, 1].mean(), rtol=1e-12)  # the mean answers it
    assert np.std(answers[:, 0]) > 0.5 and np.std(answers[:, 2]) > 0.5  # the ANFIS answers the others
    assert np.all(np.array(fit.metrics["holdout_rmse"]) > 0.25)  # at least about the noise (0.3) on every output
    assert np.mean(fit.metrics["sigma"]) > 1.2 * np.mean(fit.metrics["train_rmse"])
    with pytest.raises(ValueError):
        fit_anfis_sigma(x[:1], y[:1], max_rules=1, config=cfg)


def test_early_stopping_keeps_the_best_validation_epoch():
    """val_patience: training stops that many epochs after the lowest validation RMSE and keeps that epoch's model;
    many rules on few noisy samples overfit, so it stops before max_epochs."""
    rng = np.random.default_rng(11)
    x = rng.uniform(-2.0, 2.0, size=(160, 3))
    y = np.sin(x[:, 0]) + x[:, 1] * x[:, 2] + rng.normal(0.0, 0.5, 160)
    xn, yn = (x - x.mean(0)) / x.std(0), (y - y.mean()) / y.std()
    cfg = TrainConfig(max_epochs=40, tol=0.0, val_patience=3)
    model = TorchAnfis(an.cluster_rulebase(xn[:100], 8, seed=0), n_out=1)
    res = train(model, xn[:100], yn[:100], cfg, xn[100:], yn[100:])
    val = [h["val_rmse"] for h in res.history]
    assert res.stop_reason == "val" and res.epochs == res.best_epoch + 3 < 40
    assert res.best_epoch == int(np.argmin(val)) > 0
    with torch.no_grad():
        kept = torch.sqrt(((model.forward(xn[100:]) - model.tensor(yn[100:, None])) ** 2).mean())
    assert float(kept) == pytest.approx(min(val), rel=1e-12)
    assert min(val) < val[-1]  # it went on past the best and came back to it
    plain = train(TorchAnfis(an.cluster_rulebase(xn[:100], 8, seed=0), n_out=1), xn[:100], yn[:100],
                  TrainConfig(max_epochs=res.epochs, tol=0.0), xn[100:], yn[100:])
    assert plain.best_epoch is None and [h["val_rmse"] for h in plain.history] == pytest.approx(val, rel=1e-12)


def test_fit_anfis_sigma_chooses_its_epochs_without_the_held_out_rows():
    """With val_patience the epochs of both fits are select_epochs' choice on the oldest three quarters only; a
    target with nothing to learn (noise) chooses epoch 0, the initial model: the target's mean answers it. The
    swarms always run max_epochs."""
    rng = np.random.default_rng(12)
    x = rng.uniform(-2.0, 2.0, size=(400, 3))
    y = np.stack([np.sin(x[:, 0]) + x[:, 1], rng.normal(0.0, 1.0, 400)], axis=1)
    cfg = TrainConfig(max_epochs=30, val_patience=3)
    fit = fit_anfis_sigma(x, y, max_rules=6, config=cfg, device="cpu")
    chosen, ran = select_epochs(x[:300], y[:300], max_rules=6, config=cfg, holdout=0.25)
    assert fit.metrics["epochs"] == chosen and fit.metrics["probe_epochs"] == ran == chosen + 3
    assert 0 < chosen < 30 and fit.metrics["skill"] == [1, 0]
    noise = fit_anfis_sigma(x, y[:, 1], max_rules=6, config=cfg, device="cpu")
    assert noise.metrics["epochs"] == 0 and noise.metrics["skill"] == [0]
    np.testing.assert_allclose(an.predict(noise.arrays, noise.norm, x)[:, 0], y[:, 1].mean(), rtol=1e-12)
    for method in ("pso", "ipso"):
        swarm = fit_anfis_sigma(x, y, max_rules=6, device="cpu", config=TrainConfig(
            method=method, max_epochs=3, val_patience=3, pso=PSOConfig(n_particles=4)))
        assert swarm.metrics["epochs"] == 3 and "probe_epochs" not in swarm.metrics


def test_answer_sigma_inflates_correlated_residuals_by_the_ar1_factor():
    rng = np.random.default_rng(9)
    white = rng.normal(0.0, 1.0, (20000, 1))
    ar = np.zeros_like(white)
    for k in range(1, len(ar)):
        ar[k] = 0.8 * ar[k - 1] + white[k]
    sigma, rho = answer_sigma(np.hstack([white, ar]))
    assert rho[0] == pytest.approx(0.0, abs=0.02) and rho[1] == pytest.approx(0.8, abs=0.02)
    assert sigma[0] == pytest.approx(1.0, abs=0.03)  # independent errors: the RMS
    assert sigma[1] == pytest.approx(np.sqrt(np.mean(ar**2)) * 3.0, rel=0.05)  # sqrt(1.8 / 0.2) = 3
    sigma, rho = answer_sigma(np.array([[1.0], [-1.0], [1.0], [-1.0]]))  # anti-correlated: no deflation
    assert rho[0] == 0.0 and sigma[0] == pytest.approx(1.0)


def test_answer_sigma_takes_the_correlation_one_answer_apart():
    """Residuals at 5 Hz, answers every second: the AR(1) factor uses the autocorrelation 5 residuals apart
    (0.9^5 = 0.59), not the one of neighbouring residuals (0.9), which would inflate the sigma twice as much."""
    rng = np.random.default_rng(10)
    ar = np.zeros((40000, 1))
    for k in range(1, len(ar)):
        ar[k] = 0.9 * ar[k - 1] + rng.normal()
    t_ns = np.arange(len(ar), dtype=np.int64) * 200_000_000
    assert answer_lag(t_ns, 1.0) == 5 and answer_lag(t_ns, 0.0) == 1 and answer_lag(t_ns[:1], 1.0) == 1
    sigma, rho = answer_sigma(ar, lag=5)
    assert rho[0] == pytest.approx(0.9**5, abs=0.03)
    assert sigma[0] == pytest.approx(np.sqrt(np.mean(ar**2) * (1 + 0.9**5) / (1 - 0.9**5)), rel=0.05)
    assert answer_sigma(ar)[1][0] == pytest.approx(0.9, abs=0.02)
    with pytest.raises(ValueError):
        answer_sigma(ar, lag=0)
