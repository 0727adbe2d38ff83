"""The closed-loop error-state RTS smoother (zennav.nav.smoother).

1. Against a brute-force reference: a linear system run through a closed-loop filter (corrections fed back, as the
   engine does) and the Recorder; the smoothed states and 1-sigma equal the batch least-squares solution over the
   whole run (the exact smoother) to numerical precision, also for a row taken between two updates of an epoch, for
   a covariance reset at an epoch (bridged: the exact smoother with that epoch's result as a pseudo-measurement)
   and for one between epochs (two independent segments).
2. Through the product's replay: `zennav replay --smooth` writes both solutions and leaves the forward one
   byte-identical; on the simulated car the smoothed solution bounds a GNSS outage from both ends and its 1-sigma
   is consistent (rms(error / sigma) per state group in [0.7, 1.3]); the 21-state engine is smoothed whole.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from zennav.cli import main
from zennav.datasets import kfgins
from zennav.metrics import evaluate
from zennav.nav import earth
from zennav.nav.rotation import euler_to_dcm, quat_to_dcm
from zennav.nav.smoother import Recorder, row_errors, smooth, smooth_rows
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset, true_biases

N = 12  # 9 "navigation" states and 3 additive ones, as the smoother orders them
DT_NS = 50_000_000


def linear_system(seed: int):
    """A random stable transition Phi (N x N), full-rank Q, and measurement models of two kinds."""
    rng = np.random.default_rng(seed)
    Phi = np.eye(N) + 0.05 * rng.standard_normal((N, N))
    Phi /= max(1.0, 1.01 * np.max(np.abs(np.linalg.eigvals(Phi))))
    A = 0.1 * rng.standard_normal((N, N))
    Q = A @ A.T + 1e-3 * np.eye(N)
    H1, H2 = rng.standard_normal((3, N)), rng.standard_normal((2, N))
    return rng, Phi, Q, [(H1, 0.3 * np.eye(3)), (H2, 0.2 * np.eye(2))]


def run_closed_loop(seed: int, K: int = 40, reset_at: int | None = None, reset_between: bool = False):
    """Simulate K epochs of the linear system and run a closed-loop Kalman filter over them, recording for the
    smoother: the nominal is propagated noise-free, every update's correction dx (of z = predicted minus observed)
    is fed back (nominal -= dx). Epoch 0 starts from the prior; epochs 5, 6, 7 have no measurement; epoch 9 has a
    row taken between its two updates; reset_at: the covariance is replaced (widened, its correlations of the first
    three states removed) before that epoch's updates, or (reset_between) before its propagation.
    Returns the recorder, the per-epoch nominals after the updates, the row's nominal and the measurement log."""
    rng, Phi, Q, models = linear_system(seed)
    P0 = np.eye(N)
    x = rng.multivariate_normal(np.zeros(N), P0)  # truth
    nominal = np.zeros(N)  # the prior mean
    P = P0.copy()
    rec = Recorder()
    nominals, log = [], []
    row = None
    for k in range(K):
        t = k * DT_NS
        if k == reset_at and reset_between:
            P = widened(P)
        if k > 0:
            x = Phi @ x + rng.multivariate_normal(np.zeros(N), Q)
            nominal = Phi @ nominal
            P_new = Phi @ P @ Phi.T + Q
            rec.on_propagate(t, DT_NS / 1e9, Phi, P, P_new, nominal[9:])
            P = P_new
        if k == reset_at and not reset_between:
            P = widened(P)
        if k in (5, 6, 7):
            nominals.append(nominal.copy())
            continue
        for j, (H, R) in enumerate(models):
            y = H @ x + rng.multivariate_normal(np.zeros(len(R)), R)
            log.append((k, H, R, y))
            S = H @ P @ H.T + R
            Kg = np.linalg.solve(S, H @ P).T
            dx = Kg @ (H @ nominal - y)
            nominal = nominal - dx
            I_KH = np.eye(N) - Kg @ H
            P_new = I_KH @ P @ I_KH.T + Kg @ R @ Kg.T
            rec.on_update(t, dx, P, P_new, nominal[9:])
            P = P_new
            if k == 9 and j == 0:
                rec.mark_row(t)
                row = nominal.copy()
        nominals.append(nominal.copy())
    return rec, np.array(nominals), row, log, (Phi, Q, P0)


def widened(P: np.ndarray) -> np.ndarray:
    """A covariance reset like the engine's GNSS gate reset: states 0-2 decorrelated, their variances widened."""
    out = P.copy()
    out[0:3, :] = 0.0
    out[:, 0:3] = 0.0
    out[0:3, 0:3] = np.diag(np.diag(P)[0:3] + 9.0)
    return out


def batch_smoother(K: int, log, model, first: int = 0, prior=None, pseudo=None):
    """The exact smoother by brute force: the Gaussian posterior of all states x_first..x_K-1 given the prior of
    x_first (mean, covariance), the dynamics and every measurement, from its information matrix; pseudo: {epoch:
    (information matrix, information vector)} replacing that epoch's measurements. Returns the means (K', N) and
    1-sigma (K', N)."""
    Phi, Q, P0 = model
    mean0, cov0 = prior if prior is not None else (np.zeros(N), P0)
    M = K - first
    J = np.zeros((M * N, M * N))
    b = np.zeros(M * N)
    blk = [slice(i * N, (i + 1) * N) for i in range(M)]
    J[blk[0], blk[0]] += np.linalg.inv(cov0)
    b[blk[0]] += np.linalg.solve(cov0, mean0)
    Qi = np.linalg.inv(Q)
    for i in range(M - 1):  # x_i+1 - Phi x_i ~ N(0, Q)
        a, c = blk[i], blk[i + 1]
        J[a, a] += Phi.T @ Qi @ Phi
        J[c, c] += Qi
        J[a, c] -= Phi.T @ Qi
        J[c, a] -= Qi @ Phi
    for k, (L, eta) in (pseudo or {}).items():
        J[blk[k - first], blk[k - first]] += L
        b[blk[k - first]] += eta
    for k, H, R, y in log:
        if first <= k < K and k not in (pseudo or {}):
            i = blk[k - first]
            J[i, i] += H.T @ np.linalg.solve(R, H)
            b[i] += H.T @ np.linalg.solve(R, y)
    cov = np.linalg.inv(J)
    return np.linalg.solve(J, b).reshape(M, N), np.sqrt(np.diag(cov)).reshape(M, N)


def test_closed_loop_rts_equals_the_batch_smoother():
    K = 40
    rec, nominals, row, log, model = run_closed_loop(seed=1, K=K)
    sm = smooth(rec)
    mean, std = batch_smoother(K, log, model)
    assert sm.t_ns.tolist() == [k * DT_NS for k in range(K)] and sm.stats["segments"] == 1
    np.testing.assert_allclose(nominals - sm.s, mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.std, std, rtol=1e-9)
    np.testing.assert_allclose(sm.values, mean[:, 9:], rtol=0, atol=1e-9)
    # the forward filter alone is worse than the smoother away from the end (the test can fail)
    assert np.sqrt(np.mean((nominals[:-5] - mean[:-5]) ** 2)) > 1e-2
    # a row taken at epoch 9 between its two updates: its own nominal minus its smoothed error is the same state
    err, std_row, covered = row_errors(sm, np.array([9 * DT_NS]))
    assert covered[0]
    np.testing.assert_allclose(row - err[0], mean[9], rtol=0, atol=1e-9)
    # between epochs: interpolated error, on time
    err, std_row, covered = row_errors(sm, np.array([int(9.5 * DT_NS)]))
    np.testing.assert_allclose(err[0], 0.5 * (sm.s[9] + sm.s[10] + sm.u[10]), rtol=0, atol=1e-12)


def test_a_reset_at_an_epoch_is_bridged_by_the_epochs_own_result():
    """The gate-reset case: the smoothed run equals the exact smoother with the reset epoch's measurements replaced
    by the pseudo-measurement that takes its prior N(x-, P-) to the filter's posterior N(x+, P+)."""
    K, j = 30, 17
    rec, nominals, row, log, model = run_closed_loop(seed=2, K=K, reset_at=j)
    sm = smooth(rec)
    assert sm.stats["segments"] == 1 and sm.stats["bridged_resets"] == 1 and len(sm.t_ns) == K
    P_prior, P_post = rec.P_prior[j], rec.P_post[j]
    x_prior, x_post = model[0] @ nominals[j - 1], nominals[j]
    L = np.linalg.inv(P_post) - np.linalg.inv(P_prior)
    eta = np.linalg.solve(P_post, x_post) - np.linalg.solve(P_prior, x_prior)
    mean, std = batch_smoother(K, log, model, pseudo={j: (L, eta)})
    np.testing.assert_allclose(nominals - sm.s, mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.std, std, rtol=1e-8)
    # the reset is not a no-op: smoothing with the reset covariance as the prior gives other states
    mean_cut, _ = batch_smoother(K, [m for m in log if m[0] != j], model, pseudo={})
    assert np.max(np.abs(mean_cut - mean)) > 1e-3


def test_a_reset_between_epochs_starts_an_independent_segment():
    K, j = 30, 17
    rec, nominals, row, log, model = run_closed_loop(seed=3, K=K, reset_at=j, reset_between=True)
    sm = smooth(rec)
    assert sm.stats["segments"] == 2 and len(sm.t_ns) == K + 1 and sm.t_ns[j - 1] == sm.t_ns[j]
    # before the reset: the exact smoother of the epochs before j with their measurements
    mean, std = batch_smoother(j, [m for m in log if m[0] < j], model)
    np.testing.assert_allclose(nominals[:j] - sm.s[:j], mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.std[:j], std, rtol=1e-9)
    # from the reset on: the exact smoother from the reset covariance at epoch j-1 (the new segment's start)
    prior = (nominals[j - 1], rec.P_post[j])
    mean, std = batch_smoother(K, log, model, first=j - 1, prior=prior,
                               pseudo={j - 1: (np.zeros((N, N)), np.zeros(N))})
    np.testing.assert_allclose(nominals[j - 1:] - sm.s[j:], mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.std[j:], std, rtol=1e-9)
    # a row after the reset lies on the new segment's nominal trajectory
    err, std_row, covered = row_errors(sm, np.array([int((j - 0.5) * DT_NS)]))
    assert covered[0]
    np.testing.assert_allclose(err[0], 0.5 * (sm.s[j] + sm.s[j + 1] + sm.u[j + 1]), rtol=0, atol=1e-12)


def test_replay_smooth_writes_both_solutions_and_leaves_the_forward_one_unchanged(tmp_path):
    ds = make_dataset("car", duration_s=120.0, imu_rate_hz=100.0, seed=3)
    yaml_path = kfgins.write_dataset(ds, tmp_path / "data")
    runs = {}
    for name, extra in (("plain", []), ("smooth", ["--smooth"])):
        out = tmp_path / name
        res = CliRunner().invoke(main, ["replay", "--kf-gins-config", str(yaml_path), "--outage", "40:20",
                                        "--out", str(out), *extra])
        assert res.exit_code == 0, res.output
        runs[name] = out
    plain, smooth = runs["plain"], runs["smooth"]
    for f in ("nav.txt", "nav.csv"):  # the recorder does not change the forward pass
        assert (plain / f).read_bytes() == (smooth / f).read_bytes()
    assert not (plain / "smoothed").exists() and "smoothed" not in json.loads((plain / "metrics.json").read_text())
    fwd_csv, smo_csv = (np.loadtxt(d / "nav.csv", delimiter=",", skiprows=1) for d in (smooth, smooth / "smoothed"))
    assert (smooth / "smoothed" / "nav.csv").read_text().splitlines()[0] == (smooth / "nav.csv").read_text(
    ).splitlines()[0]
    assert smo_csv.shape == fwd_csv.shape and np.array_equal(smo_csv[:, 0], fwd_csv[:, 0])
    assert np.loadtxt(smooth / "smoothed" / "nav.txt").shape == np.loadtxt(smooth / "nav.txt").shape
    m = json.loads((smooth / "metrics.json").read_text())
    fwd, smo = m, m["smoothed"]
    assert {"horizontal_rms_m", "outages", "outage_max_horizontal_max_m", "smoother"} <= smo.keys()
    assert smo["smoother"]["segments"] == 1 and smo["smoother"]["rows_smoothed"] == len(smo_csv)
    assert smo["outage_max_horizontal_max_m"] < 0.5 * fwd["outage_max_horizontal_max_m"]
    assert np.all(smo_csv[:, 10:13] <= fwd_csv[:, 10:13] + 1e-4)  # smoothed 1-sigma never above the forward one


@pytest.fixture(scope="module")
def car_runs():
    """Three seeded 300 s simulated car drives at 100 Hz with 1 Hz GNSS, a 30 s outage at 150 s, replayed with
    smoothing (GNSS model matched: no floors on the reported sigmas)."""
    out = []
    for seed in range(3):
        ds = make_dataset("car", duration_s=300.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=seed)
        ds.config = ds.config.with_(pos_std_floor_m=0.0, vel_std_floor_mps=0.0)
        out.append((ds, run_replay(ds, outages=[(150.0, 30.0)], smoothing=True)))
    return out


def test_smoothing_bounds_the_outage_from_both_ends(car_runs):
    for ds, res in car_runs:
        fwd, smo = evaluate(ds, res), evaluate(ds, res.smoothed)
        print(ds.name, fwd["outage_max_horizontal_max_m"], smo["outage_max_horizontal_max_m"],
              fwd["horizontal_rms_m"], smo["horizontal_rms_m"])
        assert smo["outage_max_horizontal_max_m"] < 0.3 * fwd["outage_max_horizontal_max_m"]
        assert smo["horizontal_rms_m"] < 0.8 * fwd["horizontal_rms_m"]
        assert res.smoothed.status["smoother"]["segments"] == 1
    llh, v_n, q_nb, std, covered = smooth_rows(res.smoothing, res.t_ns, res.llh, res.v_n, res.q_nb, chunk=4099)
    assert np.array_equal(llh, res.smoothed.llh) and np.array_equal(q_nb, res.smoothed.q_nb)  # chunks change nothing


GROUPS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9), "gyro bias": slice(9, 12),
          "accel bias": slice(12, 15)}


def normalized_errors(ds, res) -> np.ndarray:
    """(rows, 15) smoothed error / smoothed 1-sigma once per second (biases at the epoch at or before the row)."""
    sm, smo = res.smoothing, res.smoothed
    _, std_rows, covered = row_errors(sm, smo.t_ns)
    idx = np.flatnonzero(covered)[::100]
    truth, bias = ds.truth, true_biases(ds)
    k_truth = np.searchsorted(truth.t_ns, smo.t_ns[idx])
    assert np.array_equal(truth.t_ns[k_truth], smo.t_ns[idx])
    out = np.empty((len(idx), 15))
    out[:, 0:3] = np.stack(earth.dllh_to_ned((smo.llh[idx] - truth.llh[k_truth]).T, truth.llh[k_truth, 0],
                                             truth.llh[k_truth, 2]), -1)
    out[:, 3:6] = smo.v_n[idx] - truth.v_n[k_truth]
    A = euler_to_dcm(truth.euler[k_truth]) @ np.transpose(quat_to_dcm(smo.q_nb[idx]), (0, 2, 1))  # I + [phi x]
    out[:, 6:9] = 0.5 * np.stack([A[:, 2, 1] - A[:, 1, 2], A[:, 0, 2] - A[:, 2, 0], A[:, 1, 0] - A[:, 0, 1]], -1)
    k_ep = np.searchsorted(sm.t_ns, smo.t_ns[idx], side="right") - 1
    out[:, 9:15] = sm.values[k_ep] - np.hstack([bias.gyro_bias[k_truth], bias.accel_bias[k_truth]])
    std = np.hstack([std_rows[idx, :9], sm.std[k_ep, 9:15]])
    return out / std


@pytest.mark.parametrize("group", list(GROUPS))
def test_smoothed_sigma_is_consistent_per_state_group(car_runs, group):
    runs = np.concatenate([normalized_errors(ds, res) for ds, res in car_runs])
    rms = float(np.sqrt(np.mean(runs[:, GROUPS[group]] ** 2)))
    print(f"{group}: smoothed rms(error/sigma) = {rms:.3f}")
    assert 0.7 <= rms <= 1.3, f"{group}: smoothed rms(error/sigma) = {rms:.3f}"


def test_augmented_states_are_smoothed_with_the_rest():
    """21 states (gyro and accelerometer scale factors as augmented states, simulated as the Gauss-Markov process
    the filter is told): the smoother runs on the engine's whole state, the outage is bounded as with 15 states, and
    the smoothed scale factors are consistent with their smoothed 1-sigma and, over all six, not farther from the
    simulator's than the forward filter's (mean square over the run's epochs). A multirotor, whose manoeuvres
    observe the gyro scale factors within 300 s (forward 1-sigma about 0.5-0.65 of the prior, smoothed 0.25-0.45):
    the smoother's expected gain there is larger than what one run's draw can take away. Not per axis: an axis
    left near its prior (a car's in 300 s: forward 1-sigma 0.72-1.0 of it, smoothed 0.71-1.0) gains a few % in
    expectation, and its error is one draw over the whole run, which may be farther."""
    ds = make_dataset("multirotor", duration_s=300.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=4,
                      scale_ppm=(3000.0, 3000.0))
    res = run_replay(ds, outages=[(150.0, 30.0)], smoothing=True)
    sm = res.smoothing
    assert sm is not None and res.smoothed is not None
    assert sm.s.shape[1] == 21 and sm.values.shape[1] == 12
    fwd, smo = evaluate(ds, res), evaluate(ds, res.smoothed)
    assert smo["outage_max_horizontal_max_m"] < 0.3 * fwd["outage_max_horizontal_max_m"]
    k = np.searchsorted(ds.imu.t_ns, sm.t_ns)  # the simulated scale factors at the epochs
    truth = np.concatenate([ds.notes["gyro_scale"][k], ds.notes["accel_scale"][k]], axis=1)
    forward = sm.values + sm.s[:, 9:]  # the forward filter's values after each epoch's feedback
    ms_fwd = np.mean((forward[:, 6:] - truth) ** 2, axis=0)
    ms_smo = np.mean((sm.values[:, 6:] - truth) ** 2, axis=0)
    ratio = np.sqrt(np.mean(((sm.values[:, 6:] - truth) / sm.std[:, 15:]) ** 2))
    print(f"scale factors: RMS error forward {np.round(np.sqrt(ms_fwd) * 1e6)} ppm, smoothed "
          f"{np.round(np.sqrt(ms_smo) * 1e6)} ppm, smoothed rms(error/sigma) {ratio:.2f}")
    assert ms_smo.sum() <= ms_fwd.sum()
    assert 0.5 <= ratio <= 1.5
