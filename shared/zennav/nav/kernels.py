"""The navigation engine's arithmetic, in one implementation that runs as plain Python or compiled by numba
(``compiled()``): the strapdown step (``mechanize``), the error model F (``error_model``, ``scale_factor_coupling``),
its discretisation (``discretize``), the covariance propagation (``propagate``, with the augmented
states of Navigator.add_states and the 21-state scale factors; the trapezoidal process noise folded in), the
per-sample loop between two events (``run_block``). Scalars are Python floats and tuples, matrices numpy arrays:
as Python the step-wise engine (the services) runs them without numba; compiled, ``run_block`` runs a whole stretch
of IMU samples without a Python call per sample (zennav replay), and the step-wise samples and GNSS epochs of that
engine call the compiled kernels (Navigator.kernels). Matrix products are numpy's ``@`` both ways (BLAS): compiled
and Python give the same floats.

The formulas and their literature are in zennav.nav.strapdown (mechanization) and zennav.nav.eskf (error model,
discretisation); the Navigator's ``on_imu`` (Python) and ``run_imu`` (run_block) give the same floats sample for
sample (tests/unit/test_kernels.py). ``NUMBA_DISABLE_JIT=1`` makes ``compiled()`` return these Python functions.
"""
from __future__ import annotations

import math
import types

import numpy as np

from .earth import E2 as _E2
from .earth import OMEGA_IE as _OMEGA
from .earth import A as _A
from .earth import gravity_sw
from .rotation import rotvec_quat_xyz

N_INS = 15  # INS error states (zennav.nav.eskf)


def mechanize(lat, lon, h, vn, ve, vd, q0, q1, q2, q3, ax, ay, az, ux, uy, uz, px, py, pz, wx, wy, wz, dt):
    """One strapdown step (zennav.nav.strapdown): the state (lat, lon [rad], h [m], v_n [m/s, NED], q_nb) after the
    bias-corrected increments (ax, ay, az) [rad] and (ux, uy, uz) [m/s] of an interval dt [s], body frame, with
    those of the previous interval (px, py, pz), (wx, wy, wz) for coning and sculling. Returns the 10 new values."""
    # Earth model at the start of the interval.
    sl, cl = math.sin(lat), math.cos(lat)
    w = 1.0 - _E2 * sl * sl
    sw = math.sqrt(w)
    r_n = _A / sw
    r_m = r_n * (1.0 - _E2) / w
    rmh, rnh = r_m + h, r_n + h
    tl = sl / cl
    wie_n, wie_d = _OMEGA * cl, -_OMEGA * sl
    wen_n, wen_e, wen_d = ve / rnh, -vn / rmh, -ve * tl / rnh
    s2 = sl * sl
    g = gravity_sw(s2, math.sqrt(1.0 - _E2 * s2), h)

    # Specific-force increment in b: rotation + two-sample sculling (Savage 1998).
    fx = ux + 0.5 * (ay * uz - az * uy) + ((py * uz - pz * uy) + (wy * az - wz * ay)) / 12.0
    fy = uy + 0.5 * (az * ux - ax * uz) + ((pz * ux - px * uz) + (wz * ax - wx * az)) / 12.0
    fz = uz + 0.5 * (ax * uy - ay * ux) + ((px * uy - py * ux) + (wx * ay - wy * ax)) / 12.0

    # Rotate to n with C_nb(k-1), then by (I - 0.5 zeta x) for the n-frame rotation over the interval.
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    c01 = 2.0 * (q1 * q2 - q0 * q3)
    c02 = 2.0 * (q1 * q3 + q0 * q2)
    c10 = 2.0 * (q1 * q2 + q0 * q3)
    c11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    c12 = 2.0 * (q2 * q3 - q0 * q1)
    c20 = 2.0 * (q1 * q3 - q0 * q2)
    c21 = 2.0 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    gn = c00 * fx + c01 * fy + c02 * fz
    ge = c10 * fx + c11 * fy + c12 * fz
    gd = c20 * fx + c21 * fy + c22 * fz
    zn, ze, zd = (wie_n + wen_n) * dt, wen_e * dt, (wie_d + wen_d) * dt
    dvn = gn - 0.5 * (ze * gd - zd * ge)
    dve = ge - 0.5 * (zd * gn - zn * gd)
    dvd = gd - 0.5 * (zn * ge - ze * gn)

    # Gravity and Coriolis: (g_n - (2 omega_ie_n + omega_en_n) x v_n) dt.
    cn, ce, cd = 2.0 * wie_n + wen_n, wen_e, 2.0 * wie_d + wen_d
    vn1 = vn + dvn - (ce * vd - cd * ve) * dt
    ve1 = ve + dve - (cd * vn - cn * vd) * dt
    vd1 = vd + dvd + (g - (cn * ve - ce * vn)) * dt

    # Position with the trapezoidal velocity; radii at the mid height.
    h1 = h - 0.5 * (vd + vd1) * dt
    hm = 0.5 * (h + h1)
    lat1 = lat + 0.5 * (vn + vn1) * dt / (r_m + hm)
    latm = 0.5 * (lat + lat1)
    slm = math.sin(latm)
    r_nm = _A / math.sqrt(1.0 - _E2 * slm * slm)
    lon1 = lon + 0.5 * (ve + ve1) * dt / ((r_nm + hm) * math.cos(latm))

    # Attitude: q_nb(k) = q(-zeta) * q_nb(k-1) * q(phi), phi with the two-sample coning term.
    b0, b1, b2, b3 = rotvec_quat_xyz(
        ax + (py * az - pz * ay) / 12.0, ay + (pz * ax - px * az) / 12.0, az + (px * ay - py * ax) / 12.0
    )
    r0 = q0 * b0 - q1 * b1 - q2 * b2 - q3 * b3
    r1 = q0 * b1 + q1 * b0 + q2 * b3 - q3 * b2
    r2 = q0 * b2 - q1 * b3 + q2 * b0 + q3 * b1
    r3 = q0 * b3 + q1 * b2 - q2 * b1 + q3 * b0
    n0, n1, n2, n3 = rotvec_quat_xyz(-zn, -ze, -zd)
    t0 = n0 * r0 - n1 * r1 - n2 * r2 - n3 * r3
    t1 = n0 * r1 + n1 * r0 + n2 * r3 - n3 * r2
    t2 = n0 * r2 - n1 * r3 + n2 * r0 + n3 * r1
    t3 = n0 * r3 + n1 * r2 - n2 * r1 + n3 * r0
    norm = 1.0 / math.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3)
    if t0 < 0.0:
        norm = -norm
    return lat1, lon1, h1, vn1, ve1, vd1, t0 * norm, t1 * norm, t2 * norm, t3 * norm


def quat_dcm(q0, q1, q2, q3) -> np.ndarray:
    """C_nb (3, 3) of the unit quaternion q_nb (scalar first); the products of zennav.nav.rotation.quat_to_dcm."""
    C = np.empty((3, 3))
    C[0, 0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    C[0, 1] = 2 * (q1 * q2 - q0 * q3)
    C[0, 2] = 2 * (q1 * q3 + q0 * q2)
    C[1, 0] = 2 * (q1 * q2 + q0 * q3)
    C[1, 1] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    C[1, 2] = 2 * (q2 * q3 - q0 * q1)
    C[2, 0] = 2 * (q1 * q3 - q0 * q2)
    C[2, 1] = 2 * (q2 * q3 + q0 * q1)
    C[2, 2] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return C


def error_model(F, lat, h, vn, ve, vd, C, fx, fy, fz, gb, ab) -> None:
    """Fill the 15 INS rows and columns of the zeroed F (n, n) with the continuous error dynamics
    (zennav.nav.eskf's model) at latitude lat [rad], height h [m], velocity (vn, ve, vd) [m/s], attitude C = C_nb,
    specific force (fx, fy, fz) [m/s^2, body]; gb, ab: -1/tau of the gyro and accelerometer bias processes [1/s]."""
    s, c = math.sin(lat), math.cos(lat)
    t = s / c
    sw = math.sqrt(1.0 - _E2 * s * s)
    r_n = _A / sw
    r_m = r_n * (1.0 - _E2) / (sw * sw)
    rmh, rnh = r_m + h, r_n + h
    rmh2, rnh2, rmnc2 = rmh * rmh, rnh * rnh, rmh * rnh * c * c
    w = _OMEGA
    s2 = s * s
    g = gravity_sw(s2, math.sqrt(1.0 - _E2 * s2), h)
    c00, c01, c02 = C[0, 0], C[0, 1], C[0, 2]
    c10, c11, c12 = C[1, 0], C[1, 1], C[1, 2]
    c20, c21, c22 = C[2, 0], C[2, 1], C[2, 2]
    fn, fe, fd = (c00 * fx + c01 * fy + c02 * fz, c10 * fx + c11 * fy + c12 * fz, c20 * fx + c21 * fy + c22 * fz)
    # omega_in_n = omega_ie_n + omega_en_n
    on, oe, od = w * c + ve / rnh, -vn / rmh, -w * s - ve * t / rnh
    # F_rr, I
    F[0, 0], F[0, 2], F[1, 0], F[1, 1], F[1, 2] = -vd / rmh, vn / rmh, ve * t / rnh, -(vd + vn * t) / rnh, ve / rnh
    F[0, 3], F[1, 4], F[2, 5] = 1.0, 1.0, 1.0
    # F_vr
    F[3, 0] = -2 * ve * w * c / rmh - ve * ve / rmnc2
    F[3, 2] = vn * vd / rmh2 - ve * ve * t / rnh2
    F[4, 0] = 2 * w * (vn * c - vd * s) / rmh + vn * ve / rmnc2
    F[4, 2] = (ve * vd + vn * ve * t) / rnh2
    F[5, 0] = 2 * w * ve * s / rmh
    F[5, 2] = -ve * ve / rnh2 - vn * vn / rmh2 + 2 * g / (math.sqrt(r_m * r_n) + h)
    # F_vv
    F[3, 3], F[3, 4], F[3, 5] = vd / rmh, -2 * (w * s + ve * t / rnh), vn / rmh
    F[4, 3], F[4, 4], F[4, 5] = 2 * w * s + ve * t / rnh, (vd + vn * t) / rnh, 2 * w * c + ve / rnh
    F[5, 3], F[5, 4], F[5, 5] = -2 * vn / rmh, -2 * (w * c + ve / rnh), 0.0
    # [f_n x]
    F[3, 7], F[3, 8], F[4, 6], F[4, 8], F[5, 6], F[5, 7] = -fd, fe, fd, -fn, -fe, fn
    # F_pr, F_pv
    F[6, 0], F[6, 2], F[7, 2] = -w * s / rmh, ve / rnh2, -vn / rmh2
    F[8, 0], F[8, 2] = -w * c / rmh - ve / rmnc2, -ve * t / rnh2
    F[6, 4], F[7, 3], F[8, 4] = 1 / rnh, -1 / rmh, -t / rnh
    # -[omega_in_n x]
    F[6, 7], F[6, 8], F[7, 6], F[7, 8], F[8, 6], F[8, 7] = od, -oe, -od, on, oe, -on
    F[3:6, 12:15] = -C  # accelerometer bias
    F[6:9, 9:12] = C  # gyro bias
    F[9, 9], F[10, 10], F[11, 11], F[12, 12], F[13, 13], F[14, 14] = gb, gb, gb, ab, ab, ab


def scale_factor_coupling(F, C, fx, fy, fz, ox, oy, oz, sg0, sa0) -> None:
    """Fill the columns of the gyro (from sg0) and accelerometer (from sa0) scale-factor states in F
    (zennav.nav.eskf's docstring): specific force (fx, fy, fz) [m/s^2] and rate (ox, oy, oz) [rad/s], body frame."""
    for i in range(3):
        F[3 + i, sa0] = -C[i, 0] * fx
        F[3 + i, sa0 + 1] = -C[i, 1] * fy
        F[3 + i, sa0 + 2] = -C[i, 2] * fz
        F[6 + i, sg0] = C[i, 0] * ox
        F[6 + i, sg0 + 1] = C[i, 1] * oy
        F[6 + i, sg0 + 2] = C[i, 2] * oz


def transition_matrix(F, dt):
    """Second-order transition Phi = I + F dt + (F dt)^2 / 2 over dt [s] (zennav.nav.eskf)."""
    n = F.shape[0]
    Fdt = F * dt
    Phi = Fdt @ Fdt
    Phi *= 0.5
    Phi += Fdt
    Phi.ravel()[:: n + 1] += 1.0
    return Phi


def discretize(F, q_psd, dt):
    """Transition Phi and process noise Qd over dt [s] (second-order Phi, trapezoidal Qd; zennav.nav.eskf)."""
    n = F.shape[0]
    Phi = transition_matrix(F, dt)
    Qd = (Phi * q_psd) @ Phi.T  # Phi diag(q) Phi'
    Qd.ravel()[:: n + 1] += q_psd
    Qd *= 0.5 * dt
    return Phi, Qd


def propagate(P, Phi, q_psd, dt):
    """Phi P Phi' + Qd, symmetrised, with discretize's trapezoidal Qd = (Phi Q Phi' + Q) dt / 2 of the PSD diagonal
    q_psd over dt [s] folded in: Phi (P + Q dt / 2) Phi' + Q dt / 2, one matrix triple product instead of two."""
    n = P.shape[0]
    half_q = q_psd * (0.5 * dt)
    M = P.copy()
    M.ravel()[:: n + 1] += half_q
    P1 = Phi @ M @ Phi.T
    P1.ravel()[:: n + 1] += half_q
    return 0.5 * (P1 + P1.T)


def transition(lat, h, vn, ve, vd, q0, q1, q2, q3, fx, fy, fz, ox, oy, oz, aug_decay, sg0, sa0, gb, ab, dt):
    """Phi of the whole error state (15 INS states, then the augmented ones with their F diagonal aug_decay [1/s];
    scale-factor columns from sg0 and sa0 when sg0 >= 0) over dt [s], at the navigation state (lat, h, v_n, q_nb)
    with the mean specific force f_b and rate omega_ib_b of the interval [SI, body]."""
    n = N_INS + aug_decay.shape[0]
    F = np.zeros((n, n))
    C = quat_dcm(q0, q1, q2, q3)
    error_model(F, lat, h, vn, ve, vd, C, fx, fy, fz, gb, ab)
    F.ravel()[N_INS * (n + 1):: n + 1] = aug_decay
    if sg0 >= 0:
        scale_factor_coupling(F, C, fx, fy, fz, ox, oy, oz, sg0, sa0)
    return transition_matrix(F, dt)


def run_block(t_ns, dtheta, dvel, k0, k1, t_prev_ns, stop_ns, outage_from_ns, timeout_s, nav, bias, aug_x, sg0, sa0,
              prev, cov, P, q_psd, aug_decay, gb, ab, cov_interval_s, out_nav, out_std):
    """Run IMU samples k0.. of (t_ns [ns], dtheta [rad], dvel [m/s], body) through the engine's per-sample step
    (Navigator._advance: bias and scale-factor correction, mechanization, covariance propagation every
    cov_interval_s) until k1 or before the first sample that needs the step-wise engine: one at or after stop_ns (a
    GNSS fix to fuse in it, a hook's time), non-finite or not after its predecessor (a rejection), or, from
    outage_from_ns on (-1: never), one past the outage timeout (its declaration).

    State in place: nav (10: lat, lon, h, v_n, q_nb), prev (6: the last corrected increments), cov (7: time [s],
    velocity and angle increments summed since the last propagation), P (n, n); bias (6: gyro, accelerometer) and
    aug_x (the augmented states' values; scale factors from sg0 and sa0 when sg0 >= 0) are read. Row k of out_nav
    (N, 10) and out_std (N, 9: the 1-sigma of position [m, NED], velocity [m/s, NED] and attitude error [rad], the
    square roots of P's first nine diagonal elements, as Navigator._update_stds) is the solution after sample k.
    Returns the index of the first sample not run (k1 when all ran)."""
    lat, lon, h, vn, ve, vd, q0, q1, q2, q3 = nav[0], nav[1], nav[2], nav[3], nav[4], nav[5], nav[6], nav[7], \
        nav[8], nav[9]
    px, py, pz, wx, wy, wz = prev[0], prev[1], prev[2], prev[3], prev[4], prev[5]
    cdt, cv0, cv1, cv2, ct0, ct1, ct2 = cov[0], cov[1], cov[2], cov[3], cov[4], cov[5], cov[6]
    sd = np.empty(9)
    for m in range(9):
        sd[m] = math.sqrt(P[m, m])
    bg0, bg1, bg2, ba0, ba1, ba2 = bias[0], bias[1], bias[2], bias[3], bias[4], bias[5]
    k = k0
    while k < k1:
        t = t_ns[k]
        if t >= stop_ns or t <= t_prev_ns:
            break
        if outage_from_ns >= 0 and (t - outage_from_ns) / 1_000_000_000 > timeout_s:
            break
        d0, d1, d2 = dtheta[k, 0], dtheta[k, 1], dtheta[k, 2]
        u0, u1, u2 = dvel[k, 0], dvel[k, 1], dvel[k, 2]
        if not (math.isfinite(d0) and math.isfinite(d1) and math.isfinite(d2) and math.isfinite(u0)
                and math.isfinite(u1) and math.isfinite(u2)):
            break
        dt = (t - t_prev_ns) / 1_000_000_000
        ax, ay, az = d0 - bg0 * dt, d1 - bg1 * dt, d2 - bg2 * dt
        ux, uy, uz = u0 - ba0 * dt, u1 - ba1 * dt, u2 - ba2 * dt
        if sg0 >= 0:
            i, j = sg0 - N_INS, sa0 - N_INS
            ax, ay, az = ax / (1.0 + aug_x[i]), ay / (1.0 + aug_x[i + 1]), az / (1.0 + aug_x[i + 2])
            ux, uy, uz = ux / (1.0 + aug_x[j]), uy / (1.0 + aug_x[j + 1]), uz / (1.0 + aug_x[j + 2])
        lat, lon, h, vn, ve, vd, q0, q1, q2, q3 = mechanize(lat, lon, h, vn, ve, vd, q0, q1, q2, q3, ax, ay, az,
                                                            ux, uy, uz, px, py, pz, wx, wy, wz, dt)
        px, py, pz, wx, wy, wz = ax, ay, az, ux, uy, uz
        t_prev_ns = t
        cdt += dt
        cv0 += ux
        cv1 += uy
        cv2 += uz
        ct0 += ax
        ct1 += ay
        ct2 += az
        if cdt >= cov_interval_s and cdt > 0.0:
            Phi = transition(lat, h, vn, ve, vd, q0, q1, q2, q3, cv0 / cdt, cv1 / cdt, cv2 / cdt, ct0 / cdt, ct1 / cdt,
                             ct2 / cdt, aug_decay, sg0, sa0, gb, ab, cdt)
            P[:, :] = propagate(P, Phi, q_psd, cdt)
            cdt, cv0, cv1, cv2, ct0, ct1, ct2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            for m in range(9):
                sd[m] = math.sqrt(P[m, m])
        row = out_nav[k]
        row[0], row[1], row[2], row[3], row[4] = lat, lon, h, vn, ve
        row[5], row[6], row[7], row[8], row[9] = vd, q0, q1, q2, q3
        out_std[k, :] = sd
        k += 1
    nav[0], nav[1], nav[2], nav[3], nav[4], nav[5], nav[6], nav[7], nav[8], nav[9] = lat, lon, h, vn, ve, vd, q0, \
        q1, q2, q3
    prev[0], prev[1], prev[2], prev[3], prev[4], prev[5] = px, py, pz, wx, wy, wz
    cov[0], cov[1], cov[2], cov[3], cov[4], cov[5], cov[6] = cdt, cv0, cv1, cv2, ct0, ct1, ct2
    return k


# the functions compiled() compiles, callees first (each calls the compiled versions of the others)
_KERNELS = (gravity_sw, rotvec_quat_xyz, mechanize, quat_dcm, error_model, scale_factor_coupling,
            transition_matrix, propagate, transition, run_block)
_compiled: types.SimpleNamespace | None = None


def compiled() -> types.SimpleNamespace:
    """These kernels compiled by numba (cached on disk beside their modules: the first call on a machine compiles,
    about 15 s of CPU; later processes load them in about a second), as a namespace of their names. Imports numba:
    call it only where the compiled loop pays (zennav replay of long runs), never in the services (numba adds about
    100 MB of resident memory). With NUMBA_DISABLE_JIT=1 the namespace holds the Python functions."""
    global _compiled
    if _compiled is None:
        import numba

        ns: dict = {}
        for f in _KERNELS:
            g = dict(f.__globals__)
            ns[f.__name__] = numba.njit(cache=True)(types.FunctionType(f.__code__, g, f.__name__, f.__defaults__))
        for f in _KERNELS:  # every copy calls the compiled functions (NUMBA_DISABLE_JIT=1: njit returns the copy)
            getattr(ns[f.__name__], "py_func", ns[f.__name__]).__globals__.update(ns)
        _compiled = types.SimpleNamespace(**ns)
        # load (or compile) run_block now, for the argument types Navigator.run_imu passes: a call on no samples
        z2, zi = np.zeros((1, 3)), np.zeros(1, dtype=np.int64)
        _compiled.run_block(zi, z2, z2, 0, 0, 0, 0, 0, 1.0, np.zeros(10), np.zeros(6), np.zeros(0), -1, -1,
                            np.zeros(6), np.zeros(7), np.eye(N_INS), np.zeros(N_INS), np.zeros(0), -1.0, -1.0, 0.0,
                            np.zeros((1, 10)), np.zeros((1, 9)))
        # and the kernels the step-wise engine calls with the compiled namespace (Navigator.kernels): a GNSS epoch
        _compiled.mechanize(*([0.0] * 6), 1.0, *([0.0] * 15), 1.0)
        Phi = _compiled.transition(*([0.0] * 5), 1.0, *([0.0] * 9), np.zeros(0), -1, -1, -1.0, -1.0, 1.0)
        _compiled.propagate(np.eye(N_INS), Phi, np.zeros(N_INS), 1.0)
    return _compiled
