"""Fletcher-Reeves nonlinear conjugate gradient with a strong-Wolfe line search and restarts.

References:
- R. Fletcher, C. M. Reeves, "Function minimization by conjugate gradients", Comput. J. 7 (1964) 149-154:
  d_0 = -g_0, d_k = -g_k + beta_k d_{k-1}, beta_k = g_k.g_k / g_{k-1}.g_{k-1}, x_{k+1} = x_k + alpha_k d_k.
- J. Nocedal, S. J. Wright, "Numerical Optimization", 2nd ed., Springer 2006: strong Wolfe line search
  (Alg. 3.5, zoom Alg. 3.6, cubic interpolation eq. 3.59, initial step eq. 3.60), FR with c2 < 1/2
  (sec. 5.2). Strong Wolfe includes the Armijo sufficient-decrease condition.
- M. Al-Baali, "Descent property and global convergence of the Fletcher-Reeves method with inexact line
  search", IMA J. Numer. Anal. 5 (1985) 121-124: strong Wolfe with c2 < 1/2 keeps FR directions descent.
- M. J. D. Powell, "Restart procedures for the conjugate gradient method", Math. Program. 12 (1977) 241-254:
  restart when |g_k.g_{k-1}| >= nu |g_k|^2 (nu = 0.2).
- W. W. Hager, H. Zhang, "A new conjugate gradient method with guaranteed descent and an efficient line
  search", SIAM J. Optim. 16 (2005) 170-192: secant steps and a rounding allowance in the line search.

Restarts (d_k = -g_k) happen every `restart_every` iterations (default: the dimension n), on Powell's
orthogonality test, when the FR direction is not a descent direction, after a step that met only the
Armijo condition (the line search ran out of evaluations, e.g. at a kink of f) and after a failed line search.
history[k]["restart"] names the reason when the direction taken from iterate k is -g_k by restart.

Works on 1-D numpy arrays or 1-D torch tensors alike (only +, *, @ and float() are used), so this module
imports neither; `fun(x)` returns (f, g) with g of the same type and shape as x.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

RESTART_REASONS = ("periodic", "powell", "not_descent", "armijo_only", "line_search_failure")


@dataclass
class CGResult:
    """Outcome of fr_cg. history[k] describes iterate k (k = 0 is the start point)."""

    x: Any
    f: float
    grad_norm: float
    n_iter: int
    n_fev: int
    converged: bool
    message: str
    history: list[dict] = field(default_factory=list)
    last_decrease: float | None = None  # -alpha g.d of the last accepted step (first-order decrease in f)

    @property
    def restarts(self) -> list[tuple[int, str]]:
        """(iteration, reason) of every restart, in order."""
        return [(h["k"], h["restart"]) for h in self.history if h["restart"] is not None]


def _interp_min(a0: float, f0: float, d0: float, a1: float, f1: float, d1: float) -> float | None:
    """Step minimising a model of phi from two points; None if the model has no minimiser.

    Where the derivative increases between the points, the secant root of phi' is used: it needs no
    function differences, so it stays accurate when f has no digits left to resolve the step, and it is
    exact on quadratics (Hager-Zhang use secant steps for the same reason). Otherwise the
    cubic through both points with their derivatives (Nocedal-Wright eq. 3.59).
    """
    if a0 == a1:
        return None
    if (d1 - d0) / (a1 - a0) > 0.0:
        return a1 - d1 * (a1 - a0) / (d1 - d0)
    t1 = d0 + d1 - 3.0 * (f0 - f1) / (a0 - a1)
    disc = t1 * t1 - d0 * d1
    if not disc >= 0.0:
        return None
    t2 = math.copysign(math.sqrt(disc), a1 - a0)
    den = d1 - d0 + 2.0 * t2
    if den == 0.0:
        return None
    a = a1 - (a1 - a0) * (d1 + t2 - t1) / den
    return a if math.isfinite(a) else None


def _strong_wolfe(phi, f0, d0, alpha1, c1, c2, max_evals, alpha_max, f_slack, x_rtol):
    """Step with f(alpha) <= f0 + c1 alpha d0 + f_slack and |phi'(alpha)| <= c2 |d0| (N-W Alg. 3.5, 3.6).

    f_slack absorbs rounding in f near a minimiser, where the decrease falls below f's resolution
    (the idea of Hager-Zhang's approximate Wolfe conditions).
    phi(alpha) -> (f, dphi, payload), f = dphi = inf where either is not finite (the zoom then bisects).
    The zoom gives up once its interval is narrower than x_rtol times the step (a kink of f, where
    |phi'| stays large on both sides of the minimiser, would otherwise draw all max_evals into it).
    Returns (alpha, payload, n_evals, strong): the strong Wolfe step (strong True); else, once max_evals
    are spent or the zoom gave up, the trial step of lowest f among those meeting the Armijo condition
    (strong False); else alpha None (failure).
    """
    evals = 0
    f_armijo = f0 + f_slack
    best = [math.inf, None, None]  # f, alpha, payload of the best Armijo trial step

    def trial(a):
        nonlocal evals
        f, d, pl = phi(a)
        evals += 1
        armijo = f <= f_armijo + c1 * a * d0
        if armijo and f < best[0]:
            best[:] = f, a, pl
        return f, d, pl, armijo

    def zoom(lo, flo, dlo, hi, fhi, dhi):
        while evals < max_evals:
            width = abs(hi - lo)
            if width <= x_rtol * max(abs(lo), abs(hi)):
                break
            a = _interp_min(lo, flo, dlo, hi, fhi, dhi)
            if a is None or not (min(lo, hi) + 0.01 * width <= a <= max(lo, hi) - 0.01 * width):
                a = 0.5 * (lo + hi)
            f, d, pl, armijo = trial(a)
            if not armijo or f > flo + f_slack:
                hi, fhi, dhi = a, f, d
            else:
                if abs(d) <= -c2 * d0:
                    return a, pl
                if d * (hi - lo) >= 0.0:
                    hi, fhi, dhi = lo, flo, dlo
                lo, flo, dlo = a, f, d
        return None, None

    def search():
        a_prev, f_prev, d_prev = 0.0, f0, d0
        a = min(alpha1, alpha_max)
        while evals < max_evals:
            f, d, pl, armijo = trial(a)
            if not armijo or (evals > 1 and f > f_prev + f_slack):
                return zoom(a_prev, f_prev, d_prev, a, f, d)
            if abs(d) <= -c2 * d0:
                return a, pl
            if d >= 0.0:
                return zoom(a, f, d, a_prev, f_prev, d_prev)
            if a >= alpha_max:
                return None, None
            a_next = _interp_min(a_prev, f_prev, d_prev, a, f, d)
            a_next = 2.0 * a if a_next is None else min(max(a_next, 1.1 * a), 10.0 * a)
            a_prev, f_prev, d_prev = a, f, d
            a = min(a_next, alpha_max)
        return None, None

    a_ok, pl_ok = search()
    if a_ok is not None:
        return a_ok, pl_ok, evals, True
    return best[1], best[2], evals, False


def fr_direction(g_new, g, d, gg: float, *, periodic: bool, powell_nu: float | None):
    """Next search direction -> (d_new, beta, restart reason or None).

    FR: d_new = -g_new + beta d with beta = |g_new|^2 / |g|^2 (gg = |g|^2). It restarts (d_new = -g_new,
    beta = 0) when `periodic`, on Powell's test |g_new.g| >= powell_nu |g_new|^2, or when the FR direction
    is not a descent direction (g_new.d_new >= 0).
    """
    gg_new = float(g_new @ g_new)
    if periodic:
        return -g_new, 0.0, "periodic"
    if powell_nu is not None and abs(float(g_new @ g)) >= powell_nu * gg_new:
        return -g_new, 0.0, "powell"
    beta = gg_new / gg
    d_fr = -g_new + beta * d
    if float(g_new @ d_fr) >= 0.0:
        return -g_new, 0.0, "not_descent"
    return d_fr, beta, None


def fr_cg(
    fun: Callable[[Any], tuple[Any, Any]],
    x0: Any,
    *,
    max_iter: int = 1000,
    gtol: float = 1e-6,
    ftol: float = 0.0,
    restart_every: int | None = None,
    powell_nu: float | None = 0.2,
    c1: float = 1e-4,
    c2: float = 0.1,
    max_ls_evals: int = 30,
    alpha_max: float = 1e10,
    f_rel_slack: float = 1e-12,
    first_decrease: float | None = None,
    ls_xtol: float = 1e-3,
) -> CGResult:
    """Minimise fun with Fletcher-Reeves CG.

    Stops when |g| <= gtol (converged), when an iteration lowers f by <= ftol * max(1, |f|) (converged;
    ftol=0 disables this test), after max_iter iterations, or when a line search along steepest descent
    fails. restart_every defaults to n = x0.size; powell_nu=None disables Powell's test.
    Every step satisfies the strong Wolfe conditions with 0 < c1 < c2 < 1/2 (the first of them is the
    Armijo sufficient-decrease condition, which tolerates f_rel_slack * max(1, |f|) of rounding in f), or,
    where the line search found none (max_ls_evals trial steps, or a zoom interval narrower than ls_xtol
    times the step), the Armijo condition alone, and the next direction is -g.
    The first trial step has unit length, 1/|g_0|, unless first_decrease > 0 is given: the first-order
    decrease -alpha g.d that the first step should make, e.g. CGResult.last_decrease of a previous run on a
    nearby objective (N-W eq. 3.60 carried over; the later steps use eq. 3.60 within the run).
    """
    if not 0.0 < c1 < c2 < 0.5:
        raise ValueError("strong Wolfe FR needs 0 < c1 < c2 < 1/2")
    n = int(x0.numel() if hasattr(x0, "numel") else x0.size)
    restart_every = n if restart_every is None else int(restart_every)
    if restart_every < 1:
        raise ValueError("restart_every must be >= 1")

    x = x0
    f, g = fun(x)
    f = float(f)
    n_fev = 1
    gg = float(g @ g)
    d = -g
    history: list[dict] = [dict(k=0, f=f, grad_norm=math.sqrt(gg), alpha=0.0, beta=0.0, restart=None, n_fev=1)]
    since_restart = 0
    # (alpha, g.d) of the last accepted step, for the initial-step guess alpha * g.d / g_k.d_k (N-W eq. 3.60)
    prev_step = (1.0, -float(first_decrease)) if first_decrease and first_decrease > 0.0 else None
    fresh = True  # d is the steepest-descent direction
    message, converged, k = "maximum iterations reached", False, 0

    while True:
        if math.sqrt(gg) <= gtol:
            message, converged = "gradient norm below gtol", True
            break
        if k >= max_iter:
            break
        gd = float(g @ d)
        alpha1 = 1.0 / math.sqrt(gg) if prev_step is None else prev_step[0] * prev_step[1] / gd

        def phi(a, x=x, d=d):
            fa, ga = fun(x + a * d)
            fa, da = float(fa), float(ga @ d)
            if not (math.isfinite(fa) and math.isfinite(da)):
                return math.inf, math.inf, None
            return fa, da, (fa, ga)

        slack = f_rel_slack * max(1.0, abs(f))
        alpha, new, evals, strong = _strong_wolfe(phi, f, gd, alpha1, c1, c2, max_ls_evals, alpha_max, slack,
                                                   ls_xtol)
        n_fev += evals
        if alpha is None:
            if fresh:
                message = "line search failed along steepest descent"
                break
            d, fresh, since_restart, prev_step = -g, True, 0, None
            history[-1].update(restart="line_search_failure", beta=0.0)
            continue

        k += 1
        x = x + alpha * d
        f_old, (f, g_new) = f, new
        since_restart += 1
        periodic = since_restart >= restart_every
        d, beta, restart = fr_direction(g_new, g, d, gg, periodic=periodic, powell_nu=powell_nu)
        if not strong:  # FR's descent guarantee needs the strong Wolfe step (Al-Baali)
            d, beta, restart = -g_new, 0.0, restart or "armijo_only"
        fresh = restart is not None
        if fresh:
            since_restart = 0
        prev_step = (alpha, gd)
        g, gg = g_new, float(g_new @ g_new)
        history.append(
            dict(k=k, f=f, grad_norm=math.sqrt(gg), alpha=alpha, beta=beta, restart=restart, n_fev=n_fev)
        )
        if ftol > 0.0 and f_old - f <= ftol * max(1.0, abs(f)):
            message, converged = "function decrease below ftol", True
            break
    last = None if prev_step is None else -prev_step[0] * prev_step[1]
    return CGResult(x, f, math.sqrt(gg), k, n_fev, converged, message, history, last)
