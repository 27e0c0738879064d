"""Compiled (numba) kernels of the Bayesian agent's hot path; the equations are those of `brlcli.agent.bayes`.

Why numba: at D = 30 the work per call is small (one likelihood pass over M components is M * 465 multiply-adds),
so a numpy formulation is dominated by per-call overhead (a dozen ufunc calls, each a few microseconds on the
target machine) and by a Python loop over D in the rank-1 Cholesky update. Each kernel below is one call.

Layout of the per-component caches (all indexed by component m):
- `linv[m]`: L_m^-1 packed by rows, row i (columns 0..i) at offset i (i + 1) / 2: z_i = L^-1 d is a contiguous
  dot product and only the lower triangle is stored (half the memory traffic of D x D).
- `tpar[m]`: (log normaliser, inv_scale, dof) of the Student-t, Sigma^-1 = inv_scale S^-1, dof = nu - D + 1.

Determinism: no fastmath, no parallelism; the arithmetic for one (state, component) pair is the same code whether
one component or all are evaluated, so patched cache entries are bitwise equal to a fresh pass.
"""

from __future__ import annotations

import math

import numpy as np

from brlcli.jit import jit as _jit

STEP_SIZE_CODES = {"schedule": 0, "visits": 1, "action-visits": 2}
"""`BRLParams.step_size` as the code `absorb` and `learn_every_action` take."""


@_jit
def all_finite(x: np.ndarray) -> bool:
    """True when every entry of the 1-d array x is finite."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@_jit
def chol_rank1(chol: np.ndarray, x: np.ndarray) -> None:
    """In place: chol (D, D) lower <- Cholesky factor of chol chol^T + x x^T; x (D,) is overwritten."""
    dim = x.shape[0]
    for k in range(dim):
        xk = x[k]
        if xk == 0.0:  # the rotation is the identity
            continue
        lkk = chol[k, k]
        r = math.hypot(lkk, xk)
        c = r / lkk
        s = xk / lkk
        chol[k, k] = r
        for i in range(k + 1, dim):
            col = (chol[i, k] + s * x[i]) / c
            chol[i, k] = col
            x[i] = x[i] * c - s * col


@_jit
def niw_absorb(mean: np.ndarray, scatter: np.ndarray, chol: np.ndarray, x: np.ndarray, w: float,
               kappa: float) -> None:
    """In place on one component's (mean (D,), scatter (D, D), chol (D, D)): absorb x with weight w > 0."""
    dim = x.shape[0]
    d = np.empty(dim)
    for i in range(dim):
        d[i] = x[i] - mean[i]
    coef = kappa * w / (kappa + w)  # uses the old kappa; d uses the old mean
    for i in range(dim):
        for j in range(dim):
            scatter[i, j] += coef * (d[i] * d[j])
    root = math.sqrt(coef)
    u = np.empty(dim)
    for i in range(dim):
        u[i] = root * d[i]
    chol_rank1(chol, u)
    step = w / (kappa + w)
    for i in range(dim):
        mean[i] += step * d[i]


@_jit
def refresh(chol: np.ndarray, kappa: np.ndarray, nu: np.ndarray, linv: np.ndarray, tpar: np.ndarray,
            m: int) -> None:
    """Recompute linv[m] (packed L^-1) and tpar[m] (log normaliser, inv_scale, dof) from chol[m], kappa[m], nu[m]."""
    dim = chol.shape[1]
    lo = chol[m]
    x = np.zeros((dim, dim))  # L X = I, row-oriented forward substitution (X lower triangular)
    for i in range(dim):
        x[i, i] = 1.0
    for k in range(dim):
        diag = lo[k, k]
        for j in range(k + 1):
            x[k, j] /= diag
        for i in range(k + 1, dim):
            lik = lo[i, k]
            if lik != 0.0:
                for j in range(k + 1):
                    x[i, j] -= lik * x[k, j]
    out = linv[m]
    p = 0
    for i in range(dim):
        for j in range(i + 1):
            out[p] = x[i, j]
            p += 1
    km = kappa[m]
    dof = nu[m] - dim + 1.0
    scale = (km + 1.0) / (km * dof)
    log_diag = 0.0
    for i in range(dim):
        log_diag += math.log(lo[i, i])
    log_det_sigma = dim * math.log(scale) + 2.0 * log_diag
    tpar[m, 0] = (math.lgamma(0.5 * (dof + dim)) - math.lgamma(0.5 * dof)
                  - 0.5 * dim * math.log(dof * math.pi) - 0.5 * log_det_sigma)
    tpar[m, 1] = 1.0 / scale
    tpar[m, 2] = dof


@_jit
def evaluate(states: np.ndarray, row_lo: int, row_hi: int, mean: np.ndarray, linv: np.ndarray, tpar: np.ndarray,
             lo: int, hi: int, out_ll: np.ndarray, out_dist: np.ndarray) -> None:
    """For states[row_lo:row_hi] and components lo..hi-1: log p(s|m) into out_ll, ||s - mu_m||_inf into out_dist."""
    dim = states.shape[1]
    d = np.empty(dim)
    for r in range(row_lo, row_hi):
        s = states[r]
        for m in range(lo, hi):
            mu = mean[m]
            dist = 0.0
            for i in range(dim):
                di = s[i] - mu[i]
                d[i] = di
                a = abs(di)
                if a > dist:
                    dist = a
            row = linv[m]
            acc = 0.0
            p = 0
            for i in range(dim):
                zi = 0.0  # z = L^-1 d, row i
                for j in range(i + 1):
                    zi += row[p + j] * d[j]
                p += i + 1
                acc += zi * zi
            maha = acc * tpar[m, 1]
            dof = tpar[m, 2]
            out_ll[r, m] = tpar[m, 0] - 0.5 * (dof + dim) * math.log1p(maha / dof)
            out_dist[r, m] = dist


@_jit
def _q_hat(q: np.ndarray, n: int) -> float:
    """The offset qhat = |q_min| / (1 + |q_min|) - q_min over Q[:, :n] that makes every Q + qhat positive (eq. 2)."""
    q_min = math.inf
    for a in range(q.shape[0]):
        for m in range(n):
            if q[a, m] < q_min:
                q_min = q[a, m]
    return abs(q_min) / (1.0 + abs(q_min)) - q_min


@_jit
def tables(q: np.ndarray, n: int, over_actions: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs. 2-4 from Q[:, :n] + qhat: (p(m|a) (n, A) normalised over m, or over a if over_actions; p(a); p(m))."""
    n_act = q.shape[0]
    q_hat = _q_hat(q, n)
    pma = np.empty((n, n_act))
    col = np.zeros(n_act)
    row = np.zeros(n)
    for m in range(n):
        for a in range(n_act):
            v = q[a, m] + q_hat
            pma[m, a] = v
            row[m] += v
    for a in range(n_act):
        acc = 0.0
        for m in range(n):
            acc += pma[m, a]
        col[a] = acc
    p_a = _normalised(col)
    p_m = _normalised(row)
    if over_actions:
        for m in range(n):
            t = row[m]
            ok = t > 0.0 and math.isfinite(t)
            for a in range(n_act):
                pma[m, a] = pma[m, a] / t if ok else 1.0 / n_act
    else:
        for a in range(n_act):
            t = col[a]
            ok = t > 0.0 and math.isfinite(t)
            for m in range(n):
                pma[m, a] = pma[m, a] / t if ok else 1.0 / n
    return pma, p_a, p_m


@_jit
def _normalised(x: np.ndarray) -> np.ndarray:
    """x / sum(x), or the uniform distribution where the sum is not positive and finite."""
    t = 0.0
    for i in range(x.shape[0]):
        t += x[i]
    out = np.empty_like(x)
    ok = t > 0.0 and math.isfinite(t)
    for i in range(x.shape[0]):
        out[i] = x[i] / t if ok else 1.0 / x.shape[0]
    return out


@_jit
def _shifted(ll: np.ndarray, n: int) -> np.ndarray:
    """exp(ll[:n] - max ll[:n]): likelihoods up to a common factor (all ones when the maximum is not finite)."""
    top = -math.inf
    for m in range(n):
        if ll[m] > top:
            top = ll[m]
    out = np.empty(n)
    finite = math.isfinite(top)
    for m in range(n):
        out[m] = math.exp(ll[m] - top) if finite else 1.0
    return out


@_jit
def _argmax(x: np.ndarray) -> int:
    """Index of the first maximum."""
    best = 0
    for i in range(1, x.shape[0]):
        if x[i] > x[best]:
            best = i
    return best


@_jit
def _p_action(lik: np.ndarray, pma: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """p(a|s) ∝ p(a) sum_m lik[m] p(m|a) (eq. 1), normalised."""
    n, n_act = pma.shape
    v = np.empty(n_act)
    for a in range(n_act):
        acc = 0.0
        for m in range(n):
            acc += lik[m] * pma[m, a]
        v[a] = p_a[a] * acc
    return _normalised(v)


@_jit
def action_probs(ll: np.ndarray, q: np.ndarray, n: int, over_actions: bool) -> np.ndarray:
    """p(a|s) (eq. 1) for log-likelihoods ll[:n] of one state."""
    pma, p_a, _ = tables(q, n, over_actions)
    return _p_action(_shifted(ll, n), pma, p_a)


@_jit
def _log_argmax(ll: np.ndarray, p: np.ndarray) -> int:
    """argmax_m ll[m] + log p[m] for one column p of p(m|a) (first maximum; log 0 = -inf)."""
    best, best_v = 0, -math.inf
    for m in range(p.shape[0]):
        v = ll[m] + (math.log(p[m]) if p[m] > 0.0 else -math.inf)
        if m == 0 or v > best_v:
            best, best_v = m, v
    return best


@_jit
def next_value(ll: np.ndarray, q: np.ndarray, n: int, over_actions: bool) -> float:
    """The value the TD target of `decide` takes at a next state with log-likelihoods ll[:n]: Q[a', m'] (eqs. 6-7)."""
    pma, p_a, _ = tables(q, n, over_actions)
    a_next = _argmax(_p_action(_shifted(ll, n), pma, p_a))
    return q[a_next, _log_argmax(ll, pma[:, a_next])]


@_jit
def _taken_column(q: np.ndarray, n: int, a_t: int, over_actions: bool) -> tuple[np.ndarray, np.ndarray]:
    """(p(m|a_t) (n,), p(m) (n,)): column a_t of `tables`' p(m|a) and its p(m), the same arithmetic, without the other
    actions' columns (what `decide` needs when it does not look at the next state)."""
    n_act = q.shape[0]
    q_hat = _q_hat(q, n)
    col = np.empty(n)
    row = np.zeros(n)
    for m in range(n):
        for a in range(n_act):
            row[m] += q[a, m] + q_hat
        col[m] = q[a_t, m] + q_hat
    p_m = _normalised(row)
    if over_actions:
        for m in range(n):
            t = row[m]
            col[m] = col[m] / t if t > 0.0 and math.isfinite(t) else 1.0 / n_act
    else:
        t = 0.0
        for m in range(n):
            t += col[m]
        ok = t > 0.0 and math.isfinite(t)
        for m in range(n):
            col[m] = col[m] / t if ok else 1.0 / n
    return col, p_m


@_jit
def decide(ll: np.ndarray, dist: np.ndarray, row_t: int, row_next: int, q: np.ndarray, n: int, a_t: int,
           reward: float, gamma: float, t_l: float, t_u: float,
           reference_code: bool) -> tuple[float, int, float, float, int]:
    """Steps 1-3 of Algorithm 1 and the weight of eq. 9 for m_t: (td, m_t, d_t, weight, case 0 good/1 bad/2 neutral).
    With gamma 0 and a reward other than 0, reward + gamma Q[a', m'] is the reward exactly (Q is finite), so a' and
    m' are not computed and only p(m|a_t) of eqs. 2-4 is."""
    skip_next = gamma == 0.0 and reward != 0.0
    if skip_next:
        pm_a, p_m = _taken_column(q, n, a_t, reference_code)
    else:
        pma, p_a, p_m = tables(q, n, reference_code)
        pm_a = pma[:, a_t]
    ll_t = ll[row_t]
    dt = dist[row_t]
    m_t = 0
    for m in range(1, n):
        if dt[m] < dt[m_t]:
            m_t = m
    lik = _shifted(ll_t, n)
    m_delta = _log_argmax(ll_t, pm_a) if reference_code else m_t
    if skip_next:
        td = reward - q[a_t, m_delta]
    else:
        ll_next = ll[row_next]
        a_next = _argmax(_p_action(_shifted(ll_next, n), pma, p_a))
        m_next = _log_argmax(ll_next, pma[:, a_next])
        td = reward + gamma * q[a_next, m_next] - q[a_t, m_delta]
    num = np.empty(n)
    if td > t_u:
        case = 0
        for m in range(n):
            num[m] = lik[m] * pm_a[m]
    elif td < t_l:
        case = 1
        if n == 1:  # p(m|a) = 1 makes eq. 10 0/0; defined as 1 for the only component
            return td, m_t, dt[m_t], 1.0, case
        for m in range(n):
            num[m] = lik[m] * (1.0 - pm_a[m])
    else:
        case = 2
        for m in range(n):
            num[m] = lik[m] * p_m[m]
    return td, m_t, dt[m_t], _normalised(num)[m_t], case


@_jit
def absorb(m: int, a_t: int, s_t: np.ndarray, td: float, weight: float, alpha: float, step_size: int,
           q: np.ndarray, visits: np.ndarray, mean: np.ndarray, kappa: np.ndarray, nu: np.ndarray,
           scatter: np.ndarray, chol: np.ndarray, linv: np.ndarray, tpar: np.ndarray, cache_states: np.ndarray,
           cache_ll: np.ndarray, cache_dist: np.ndarray) -> None:
    """The Q update (eq. 8) with weight w and the step size of code `step_size`, then the fractional NIW update of
    component m and its cached L^-1, Student-t constants and cache entries (`BayesianAgent._update`)."""
    dim = mean.shape[1]
    kappa_m = kappa[m]
    step = alpha
    if step_size == 1:
        step = min(step, 1.0 / (kappa_m - dim))
    elif step_size == 2:
        step = min(step, 1.0 / (visits[a_t, m] + 1.0))
    q[a_t, m] += step * weight * td
    visits[a_t, m] += weight
    if weight == 0.0:
        return
    niw_absorb(mean[m], scatter[m], chol[m], s_t, weight, kappa_m)
    kappa[m] = kappa_m + weight
    nu[m] += weight
    refresh(chol, kappa, nu, linv, tpar, m)
    evaluate(cache_states, 0, cache_states.shape[0], mean, linv, tpar, m, m + 1, cache_ll, cache_dist)


@_jit
def create(m: int, at: np.ndarray, init_scatter: float, init_q: float, q: np.ndarray, visits: np.ndarray,
           mean: np.ndarray, kappa: np.ndarray, nu: np.ndarray, scatter: np.ndarray, chol: np.ndarray, linv: np.ndarray,
           tpar: np.ndarray, cache_states: np.ndarray, cache_ll: np.ndarray, cache_dist: np.ndarray) -> None:
    """Component m at `at`: nu = D, kappa = D + 1, S = init_scatter I, Q = init_q, no visits; its cached L^-1,
    Student-t constants and cache entries (`BayesianAgent._add_component`)."""
    dim = mean.shape[1]
    mean[m] = at
    nu[m] = dim
    kappa[m] = dim + 1
    scatter[m] = 0.0
    chol[m] = 0.0
    root = math.sqrt(init_scatter)
    for i in range(dim):
        scatter[m, i, i] = init_scatter
        chol[m, i, i] = root
    q[:, m] = init_q
    visits[:, m] = 0.0
    refresh(chol, kappa, nu, linv, tpar, m)
    evaluate(cache_states, 0, cache_states.shape[0], mean, linv, tpar, m, m + 1, cache_ll, cache_dist)


@_jit
def learn_every_action(row_t: int, rewards: np.ndarray, n: int, alpha: float, tau: float, rho: float,
                       scalars: np.ndarray, codes: np.ndarray, q: np.ndarray, visits: np.ndarray, mean: np.ndarray,
                       kappa: np.ndarray, nu: np.ndarray, scatter: np.ndarray, chol: np.ndarray, linv: np.ndarray,
                       tpar: np.ndarray, cache_states: np.ndarray, cache_ll: np.ndarray,
                       cache_dist: np.ndarray) -> tuple[int, float, float, float]:
    """`BayesianAgent.learn(s, a, rewards[a], s, next_value=0.0)` for a = 0, 1, ... in turn, s the state in cache row
    row_t, the same arithmetic in the same order: returns (n, alpha, tau, rho) after them. The arrays need room for
    one new component per action. scalars: (gamma, T_l, T_u, alpha_rate, alpha_final, tau_rate, tau_final, rho_rate,
    rho_final, init_scatter, init_q, new_q_taken); codes: (reference_code, step_size code, max_components, new_q
    nearest, at_capacity merge)."""
    gamma, t_l, t_u = scalars[0], scalars[1], scalars[2]
    reference_code, step_size, max_components = codes[0] != 0, codes[1], codes[2]
    nearest, merge = codes[3] != 0, codes[4] != 0
    s_t = cache_states[row_t].copy()
    for a_t in range(rewards.shape[0]):
        reward_in = rewards[a_t] + gamma * 0.0
        td, m_t, d_t, weight, _ = decide(cache_ll, cache_dist, row_t, row_t, q, n, a_t, reward_in, 0.0, t_l, t_u,
                                         reference_code)
        if d_t < rho or td > t_l:
            absorb(m_t, a_t, s_t, td, weight, alpha, step_size, q, visits, mean, kappa, nu, scatter, chol, linv,
                   tpar, cache_states, cache_ll, cache_dist)
        elif n < max_components:
            m = n
            create(m, s_t, scalars[9], scalars[10], q, visits, mean, kappa, nu, scatter, chol, linv, tpar, cache_states,
                   cache_ll, cache_dist)
            n = m + 1
            if nearest:
                q[:, m] = q[:, m_t]
                q[a_t, m] = q[a_t, m_t] + td
            else:
                q[a_t, m] = scalars[11]
        elif merge:
            absorb(m_t, a_t, s_t, td, weight, alpha, step_size, q, visits, mean, kappa, nu, scatter, chol, linv,
                   tpar, cache_states, cache_ll, cache_dist)
        alpha += scalars[3] * (scalars[4] - alpha)
        tau += scalars[5] * (scalars[6] - tau)
        rho += scalars[7] * (scalars[8] - rho)
    return n, alpha, tau, rho
