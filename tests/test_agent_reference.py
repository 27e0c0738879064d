"""The fast agent against a plain, loop-based, slow implementation of the same equations (issue 11).

`ReferenceAgent` is written for this test from docs/method.md and the docstring of `BayesianAgent.learn`:
its own Student-t log density (numpy.linalg on the scale matrix Sigma, no Cholesky caches), the NIW update
from its definition, eqs. 1-11 and Algorithm 1 with Python loops over components and actions. Both agents are
driven side by side on one random stream; every step must agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from brlcli.agent import BayesianAgent, BRLParams, log_likelihoods

D = 30
A = 4
TOL = 1e-9


class ReferenceAgent:
    """Slow, obviously-correct Bayesian agent: lists of components, loops everywhere."""

    def __init__(self, dim: int, n_actions: int, params: BRLParams) -> None:
        self.dim, self.n_actions, self.p = dim, n_actions, params
        self.alpha, self.tau, self.rho = params.alpha_init, params.tau_init, params.rho_init
        self.means: list[np.ndarray] = []
        self.kappa: list[float] = []
        self.nu: list[float] = []
        self.scatter: list[np.ndarray] = []
        self.q: list[list[float]] = [[] for _ in range(n_actions)]  # q[a][m]
        self.create(np.full(dim, 1.0 / dim))

    def create(self, mean: np.ndarray) -> int:
        """A new component at mean: nu = D, kappa = D + 1, S = init_scatter I, Q column init_q."""
        self.means.append(np.array(mean, dtype=float))
        self.kappa.append(self.dim + 1.0)
        self.nu.append(float(self.dim))
        self.scatter.append(self.p.init_scatter * np.eye(self.dim))
        for a in range(self.n_actions):
            self.q[a].append(self.p.init_q)
        return len(self.means) - 1

    @property
    def n(self) -> int:
        """Number of components."""
        return len(self.means)

    def log_pdf(self, x: np.ndarray, m: int) -> float:
        """log St(x; mu_m, (kappa+1)/(kappa nu') S_m, nu'), nu' = nu - D + 1, from its formula."""
        dim = self.dim
        dof = self.nu[m] - dim + 1.0
        sigma = (self.kappa[m] + 1.0) / (self.kappa[m] * dof) * self.scatter[m]
        sign, log_det = np.linalg.slogdet(sigma)
        assert sign > 0
        d = x - self.means[m]
        maha = float(d @ np.linalg.solve(sigma, d))
        return (math.lgamma((dof + dim) / 2) - math.lgamma(dof / 2) - dim / 2 * math.log(dof * math.pi)
                - 0.5 * log_det - (dof + dim) / 2 * math.log1p(maha / dof))

    def tables(self) -> tuple[list[list[float]], list[float], list[float]]:
        """Eqs. 2-4: p(m|a) as pma[m][a], p(a), p(m) from Q + qhat."""
        n, n_act = self.n, self.n_actions
        q_min = min(self.q[a][m] for a in range(n_act) for m in range(n))
        q_hat = abs(q_min) / (1 + abs(q_min)) - q_min
        shifted = [[self.q[a][m] + q_hat for a in range(n_act)] for m in range(n)]
        pma = [[0.0] * n_act for _ in range(n)]
        if self.p.variant == "paper":  # normalised over components
            for a in range(n_act):
                total = sum(shifted[m][a] for m in range(n))
                for m in range(n):
                    pma[m][a] = shifted[m][a] / total if total > 0 else 1.0 / n
        else:  # reference code: normalised over actions
            for m in range(n):
                total = sum(shifted[m])
                for a in range(n_act):
                    pma[m][a] = shifted[m][a] / total if total > 0 else 1.0 / n_act
        col = [sum(shifted[m][a] for m in range(n)) for a in range(n_act)]
        row = [sum(shifted[m]) for m in range(n)]
        p_a = [c / sum(col) if sum(col) > 0 else 1.0 / n_act for c in col]
        p_m = [r / sum(row) if sum(row) > 0 else 1.0 / n for r in row]
        return pma, p_a, p_m

    def likelihoods(self, x: np.ndarray) -> tuple[list[float], list[float]]:
        """(log p(x|m), p(x|m) / max_m p(x|m)) for every component."""
        ll = [self.log_pdf(x, m) for m in range(self.n)]
        top = max(ll)
        return ll, [math.exp(v - top) for v in ll]

    def p_action(self, x: np.ndarray) -> list[float]:
        """Eq. 1: p(a|s) ∝ p(a) sum_m p(s|m) p(m|a)."""
        pma, p_a, _ = self.tables()
        _, lik = self.likelihoods(x)
        v = [p_a[a] * sum(lik[m] * pma[m][a] for m in range(self.n)) for a in range(self.n_actions)]
        total = sum(v)
        return [x / total for x in v] if total > 0 else [1.0 / self.n_actions] * self.n_actions

    def act(self, x: np.ndarray, rng: np.random.Generator) -> int:
        """Eq. 11: greedy action with (1 - tau)/|A| + tau, the others (1 - tau)/|A|; inverse-CDF draw."""
        probs = self.p_action(x)
        greedy = probs.index(max(probs))
        policy = [(1.0 - self.tau) / self.n_actions] * self.n_actions
        policy[greedy] += self.tau
        cumulative = [sum(policy[: a + 1]) for a in range(self.n_actions)]
        u = rng.random() * cumulative[-1]
        return min(sum(1 for c in cumulative if c <= u), self.n_actions - 1)

    def learn(self, s: np.ndarray, a_t: int, r: float, s2: np.ndarray) -> dict:
        """Algorithm 1 as documented by BayesianAgent.learn."""
        p, n = self.p, self.n
        pma, _, p_m = self.tables()
        ll_next, _ = self.likelihoods(s2)
        probs = self.p_action(s2)
        a_next = probs.index(max(probs))

        def log_argmax(ll: list[float], a: int) -> int:
            scores = [ll[m] + (math.log(pma[m][a]) if pma[m][a] > 0 else -math.inf) for m in range(n)]
            return scores.index(max(scores))

        m_next = log_argmax(ll_next, a_next)
        dist = [max(abs(s[i] - self.means[m][i]) for i in range(self.dim)) for m in range(n)]
        m_t = dist.index(min(dist))
        ll_t, lik = self.likelihoods(s)
        m_delta = m_t if p.variant == "paper" else log_argmax(ll_t, a_t)
        td = r + p.gamma * self.q[a_next][m_next] - self.q[a_t][m_delta]
        if td > p.T_u:
            num, case = [lik[m] * pma[m][a_t] for m in range(n)], "good"
        elif td < p.T_l:
            num, case = [lik[m] * (1.0 - pma[m][a_t]) for m in range(n)], "bad"
        else:
            num, case = [lik[m] * p_m[m] for m in range(n)], "neutral"
        if case == "bad" and n == 1:
            w = 1.0
        else:
            w = num[m_t] / sum(num) if sum(num) > 0 else 1.0 / n
        if dist[m_t] < self.rho or td > p.T_l:
            self.update(m_t, a_t, s, td, w)
            out = {"td": td, "component": m_t, "created": False, "weight": w, "case": case}
        elif n < p.max_components:
            new = self.create(s)
            self.q[a_t][new] = p.new_q_taken
            out = {"td": td, "component": new, "created": True, "weight": math.nan, "case": "created"}
        elif p.at_capacity == "merge":
            self.update(m_t, a_t, s, td, w)
            out = {"td": td, "component": m_t, "created": False, "weight": w, "case": "capacity"}
        else:
            out = {"td": td, "component": m_t, "created": False, "weight": 0.0, "case": "capacity"}
        self.alpha += p.alpha_rate * (p.alpha_final - self.alpha)
        self.tau += p.tau_rate * (p.tau_final - self.tau)
        self.rho += p.rho_rate * (p.rho_final - self.rho)
        return out

    def update(self, m: int, a: int, x: np.ndarray, td: float, w: float) -> None:
        """Eq. 8 and the NIW posterior after x with fractional count w (old kappa and mean on the right)."""
        self.q[a][m] += self.alpha * w * td
        kappa, mu = self.kappa[m], self.means[m]
        d = x - mu
        self.scatter[m] = self.scatter[m] + kappa * w / (kappa + w) * np.outer(d, d)
        self.means[m] = mu + w / (kappa + w) * d
        self.kappa[m] = kappa + w
        self.nu[m] = self.nu[m] + w


def drive(params: BRLParams, steps: int, seed: int) -> tuple[BayesianAgent, ReferenceAgent, list[str]]:
    """Run both agents on one stream (act with equal generators, then learn); assert they agree at every step."""
    fast, ref = BayesianAgent(D, A, params), ReferenceAgent(D, A, params)
    stream = np.random.default_rng(seed)
    rng_fast, rng_ref = np.random.default_rng(seed + 100), np.random.default_rng(seed + 100)
    cases = []
    s = stream.dirichlet(np.full(D, 0.3))
    for t in range(steps):
        a = fast.act(s, rng_fast)
        assert a == ref.act(s, rng_ref), t
        if stream.random() < 0.5:  # a fresh far state, or a small move near the current one
            s2 = stream.dirichlet(np.full(D, 0.3))
        else:
            s2 = np.abs(s + stream.normal(0.0, 0.004, D))
            s2 /= s2.sum()
        r = float(stream.uniform(-40.0, 5.0))
        got, want = fast.learn(s, a, r, s2), ref.learn(s, a, r, s2)
        assert (got.component, got.created, got.weight_case) == (want["component"], want["created"], want["case"]), t
        assert got.td_error == pytest.approx(want["td"], rel=TOL, abs=TOL), t
        if want["created"]:
            assert math.isnan(got.weight)
        else:
            assert got.weight == pytest.approx(want["weight"], rel=TOL, abs=TOL), t
        assert got.n_components == ref.n
        np.testing.assert_allclose(fast.Q, np.array(ref.q), rtol=TOL, atol=TOL, err_msg=str(t))
        cases.append(got.weight_case)
        s = s2
    np.testing.assert_allclose(fast.means, np.array(ref.means), rtol=TOL, atol=TOL)
    np.testing.assert_allclose(fast.scatter, np.array(ref.scatter), rtol=TOL, atol=1e-12)
    np.testing.assert_allclose(fast.kappa, ref.kappa, rtol=TOL)
    np.testing.assert_allclose(fast.nu, ref.nu, rtol=TOL)
    assert (fast.alpha, fast.tau, fast.rho) == pytest.approx((ref.alpha, ref.tau, ref.rho), rel=1e-14)
    x = stream.dirichlet(np.full(D, 0.3))
    np.testing.assert_allclose(log_likelihoods(fast, x), ref.likelihoods(x)[0], rtol=1e-9)
    np.testing.assert_allclose(fast.action_probabilities(x), ref.p_action(x), rtol=1e-9, atol=1e-12)
    return fast, ref, cases


def test_fast_agent_equals_reference_paper_variant() -> None:
    fast, _, cases = drive(BRLParams(max_components=32), steps=1000, seed=1)
    created = cases.count("created")
    assert created >= 20 and fast.n_components == 1 + created
    assert {"good", "bad", "neutral", "created", "capacity"} <= set(cases)  # every branch of Algorithm 1 ran


def test_fast_agent_equals_reference_code_variant_with_skip() -> None:
    params = BRLParams.reference_code(max_components=24, at_capacity="skip")
    fast, _, cases = drive(params, steps=300, seed=2)
    assert cases.count("created") == 23 and "capacity" in cases and fast.n_components == 24
    assert {"good", "bad", "neutral"} <= set(cases)


def test_cached_likelihoods_equal_a_fresh_pass() -> None:
    # the agent caches log p(s|m) of recent states and patches one component per update: the cache must be
    # invisible, i.e. bitwise equal to evaluating every component afresh
    fast, _, _ = drive(BRLParams(max_components=32), steps=60, seed=3)
    for row, key in enumerate(fast._cache_keys):
        assert key is not None
        state = np.frombuffer(key)
        fresh = fast._log_lik(state[None, :])[0]
        assert np.array_equal(fast._cache_ll[row, :fast.n_components], fresh)
        assert np.array_equal(fast._cache_dist[row, :fast.n_components], np.abs(fast.means - state).max(axis=1))
