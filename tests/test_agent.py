"""Tests of the Bayesian RL agent against independent oracles (scipy densities, batch NIW formulas)."""

from __future__ import annotations

import math
import os
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import multivariate_t

from brlcli.agent import (
    BayesianAgent,
    BRLParams,
    LearnStep,
    chol_rank1_update,
    forward_substitution,
    log_likelihoods,
    niw_update,
    student_t_logpdf,
)
from brlcli.agent.bayes import deployment_arrays, save_model_arrays
from brlcli.errors import BrlInputError

D = 30
A = 4


# ---------------------------------------------------------------------------------------------------------------
# helpers: an independent, linear-space implementation of one learning step with scipy densities
# ---------------------------------------------------------------------------------------------------------------

def scipy_densities(agent: BayesianAgent, x: np.ndarray) -> np.ndarray:
    """p(x|m) for every component via scipy.stats.multivariate_t (linear space)."""
    dim = agent.state_dim
    out = []
    for mu, kappa, nu, scatter in zip(agent.means, agent.kappa, agent.nu, agent.scatter, strict=True):
        dof = nu - dim + 1
        out.append(multivariate_t(loc=mu, shape=(kappa + 1) / (kappa * dof) * scatter, df=dof).pdf(x))
    return np.array(out)


def offset_tables(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper eqs. 2-4: (p(m|a) (M, A) normalised over m, p(a), p(m))."""
    q_min = q.min()
    q_hat = abs(q_min) / (1 + abs(q_min)) - q_min
    shifted = q.T + q_hat
    return shifted / shifted.sum(axis=0), shifted.sum(axis=0) / shifted.sum(), shifted.sum(axis=1) / shifted.sum()


def oracle_step(agent: BayesianAgent, s: np.ndarray, a: int, r: float, s2: np.ndarray) -> dict:
    """What learn(s, a, r, s2) must do, per docs/method.md, computed without the agent's code."""
    p = agent.params
    q = agent.Q
    p_m_a, p_a, p_m = offset_tables(q)
    lik_next = scipy_densities(agent, s2)
    a_next = int(np.argmax(p_a * (lik_next @ p_m_a)))
    m_next = int(np.argmax(lik_next * p_m_a[:, a_next]))
    dist = np.abs(agent.means - s).max(axis=1)
    m_t = int(np.argmin(dist))
    td = r + p.gamma * q[a_next, m_next] - q[a, m_t]
    if not (dist[m_t] < agent.rho or td > p.T_l):
        return {"td": td, "case": "created", "m_t": m_t, "a_next": a_next, "m_next": m_next}
    lik = scipy_densities(agent, s)
    if td > p.T_u:
        num, case = lik * p_m_a[:, a], "good"
    elif td < p.T_l:
        num, case = lik * (1 - p_m_a[:, a]), "bad"
    else:
        num, case = lik * p_m, "neutral"
    w = 1.0 if (case == "bad" and len(lik) == 1) else num[m_t] / num.sum()
    return {"td": td, "case": case, "m_t": m_t, "w": w, "a_next": a_next, "m_next": m_next}


def far_state(dim: int, hot: int) -> np.ndarray:
    """A normalised state with most mass in entry `hot` (l_inf-far from the uniform initial mean)."""
    s = np.full(dim, 0.1 / (dim - 1))
    s[hot] = 0.9
    return s


def trained_agent(n_steps: int = 120, seed: int = 3, params: BRLParams | None = None) -> BayesianAgent:
    """A D = 30 agent after random steps: several components, several of them updated."""
    rng = np.random.default_rng(seed)
    agent = BayesianAgent(D, A, params or BRLParams())
    for _ in range(n_steps):
        s, s2 = rng.dirichlet(np.full(D, 0.3)), rng.dirichlet(np.full(D, 0.3))
        agent.learn(s, int(rng.integers(A)), float(rng.uniform(-60, 5)), s2)
    return agent


def assert_agents_identical(x: BayesianAgent, y: BayesianAgent) -> None:
    """Bit-identical model state."""
    for name in ("Q", "visits", "means", "kappa", "nu", "scatter", "chol"):  # bytes: signed zeros count
        u, v = getattr(x, name), getattr(y, name)
        assert u.shape == v.shape and u.tobytes() == v.tobytes(), name
    assert (x.alpha, x.tau, x.rho, x.steps, x.n_components) == (y.alpha, y.tau, y.rho, y.steps, y.n_components)
    assert x.params == y.params


def same_step(u: LearnStep, v: LearnStep) -> bool:
    """LearnStep equality that treats nan weights as equal."""
    weights_equal = (math.isnan(u.weight) and math.isnan(v.weight)) or u.weight == v.weight
    return weights_equal and replace(u, weight=0.0) == replace(v, weight=0.0)


# ---------------------------------------------------------------------------------------------------------------
# densities
# ---------------------------------------------------------------------------------------------------------------

def test_log_density_matches_scipy_multivariate_t() -> None:
    agent = trained_agent()
    assert agent.n_components >= 4
    assert (agent.kappa > D + 1).sum() >= 2  # several components have absorbed weighted points
    rng = np.random.default_rng(0)
    states = np.vstack([rng.dirichlet(np.full(D, 0.3), size=3), agent.means[:2] + 0.01])
    ours_batch = student_t_logpdf(states, agent.means, agent.chol, agent.kappa, agent.nu)
    for i, x in enumerate(states):
        expected = []
        for mu, kappa, nu, scatter in zip(agent.means, agent.kappa, agent.nu, agent.scatter, strict=True):
            dof = nu - D + 1
            expected.append(multivariate_t(loc=mu, shape=(kappa + 1) / (kappa * dof) * scatter, df=dof).logpdf(x))
        np.testing.assert_allclose(log_likelihoods(agent, x), expected, rtol=1e-8)
        np.testing.assert_allclose(ours_batch[i], expected, rtol=1e-8)
        np.testing.assert_allclose(student_t_logpdf(x, agent.means, agent.chol, agent.kappa, agent.nu), expected,
                                   rtol=1e-8)


def test_forward_substitution_matches_solve() -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(size=(5, 6, 6))
    chol = np.linalg.cholesky(a @ a.transpose(0, 2, 1) + np.eye(6))
    b = rng.normal(size=(3, 5, 6))
    expected = np.linalg.solve(chol[None], b[..., None])[..., 0]
    np.testing.assert_allclose(forward_substitution(chol, b), expected, rtol=1e-10, atol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# NIW update and Cholesky factor
# ---------------------------------------------------------------------------------------------------------------

def test_chol_rank1_update_matches_cholesky() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(size=(D, D))
    scatter = a @ a.T + 0.1 * np.eye(D)
    chol = np.linalg.cholesky(scatter)
    x = rng.normal(size=D)
    x[:3] = 0.0  # leading zero entries take the identity-rotation shortcut
    chol_rank1_update(chol, x)
    np.testing.assert_allclose(chol, np.linalg.cholesky(scatter + np.outer(x, x)), rtol=1e-9, atol=1e-12)


def test_fractional_niw_updates_equal_batch_posterior() -> None:
    rng = np.random.default_rng(4)
    mu0, kappa0, nu0, s0 = np.full(D, 1.0 / D), D + 1.0, float(D), 0.1 * np.eye(D)
    points = rng.dirichlet(np.full(D, 0.5), size=9)
    weights = rng.uniform(0.05, 1.0, size=9)
    mean, scatter, chol, kappa, nu = mu0.copy(), s0.copy(), np.sqrt(0.1) * np.eye(D), kappa0, nu0
    for x, w in zip(points, weights, strict=True):
        kappa, nu = niw_update(mean, kappa, nu, scatter, chol, x, float(w))
    total = weights.sum()
    xbar = weights @ points / total
    centred = points - xbar
    batch_scatter = (s0 + (weights[:, None] * centred).T @ centred
                     + kappa0 * total / (kappa0 + total) * np.outer(xbar - mu0, xbar - mu0))
    np.testing.assert_allclose(mean, (kappa0 * mu0 + total * xbar) / (kappa0 + total), rtol=1e-12)
    np.testing.assert_allclose(kappa, kappa0 + total, rtol=1e-13)
    np.testing.assert_allclose(nu, nu0 + total, rtol=1e-13)
    np.testing.assert_allclose(scatter, batch_scatter, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(chol, np.linalg.cholesky(batch_scatter), rtol=1e-9, atol=1e-12)


def test_agent_update_applies_niw_step_and_keeps_cholesky_consistent() -> None:
    agent = trained_agent(n_steps=60)
    rng = np.random.default_rng(5)
    for _ in range(20):
        s, s2 = rng.dirichlet(np.full(D, 0.3)), rng.dirichlet(np.full(D, 0.3))
        before = {k: getattr(agent, k) for k in ("means", "kappa", "nu", "scatter", "Q")}
        alpha = agent.alpha
        a = int(rng.integers(A))
        step = agent.learn(s, a, float(rng.uniform(-9, 0)), s2)  # td > T_l: always an update
        assert not step.created
        m, w = step.component, step.weight
        kappa = before["kappa"][m]
        d = s - before["means"][m]
        np.testing.assert_allclose(agent.means[m], before["means"][m] + w / (kappa + w) * d, rtol=1e-12)
        np.testing.assert_allclose(agent.scatter[m], before["scatter"][m] + kappa * w / (kappa + w) * np.outer(d, d),
                                   rtol=1e-12)
        assert agent.kappa[m] == pytest.approx(kappa + w, rel=1e-14)
        assert agent.nu[m] == pytest.approx(before["nu"][m] + w, rel=1e-14)
        assert agent.Q[a, m] == pytest.approx(before["Q"][a, m] + alpha * w * step.td_error, rel=1e-12)
        other = np.arange(agent.n_components) != m
        assert np.array_equal(agent.means[other], before["means"][other])
    for m in range(agent.n_components):
        np.testing.assert_allclose(agent.chol[m], np.linalg.cholesky(agent.scatter[m]), rtol=1e-8, atol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# probabilities
# ---------------------------------------------------------------------------------------------------------------

def test_probabilities_normalised_and_offset_with_negative_q() -> None:
    agent = trained_agent(n_steps=40)
    rng = np.random.default_rng(6)
    agent._q[:, :agent.n_components] = -rng.uniform(0.0, 50.0, size=(A, agent.n_components))
    p_m_a, p_a, p_m = agent._probability_tables()
    q = agent.Q
    assert q.max() < 0
    assert (p_m_a > 0).all() and (p_a > 0).all() and (p_m > 0).all()
    np.testing.assert_allclose(p_m_a.sum(axis=0), 1.0, rtol=1e-12)
    exp_m_a, exp_a, exp_m = offset_tables(q)
    np.testing.assert_allclose(p_m_a, exp_m_a, rtol=1e-12)
    np.testing.assert_allclose(p_a, exp_a, rtol=1e-12)
    np.testing.assert_allclose(p_m, exp_m, rtol=1e-12)
    for _ in range(5):
        probs = agent.action_probabilities(rng.dirichlet(np.full(D, 0.3)))
        assert probs.shape == (A,)
        assert probs.sum() == pytest.approx(1.0, abs=1e-12)
        assert (probs >= 0).all()


def test_action_probabilities_equal_eq1_in_linear_space() -> None:
    agent = BayesianAgent(3, 3)
    agent.learn(far_state(3, 0), 1, -60.0, far_state(3, 0))
    agent.learn(far_state(3, 2), 2, -60.0, far_state(3, 1))
    assert agent.n_components == 3
    agent._q[:, :3] = np.array([[0.3, -2.0, 1.0], [0.1, 0.5, -0.7], [2.0, 0.0, 0.2]])
    p_m_a, p_a, _ = offset_tables(agent.Q)
    for x in (np.array([0.5, 0.3, 0.2]), far_state(3, 2), np.array([0.1, 0.1, 0.8])):
        expected = p_a * (scipy_densities(agent, x) @ p_m_a)
        np.testing.assert_allclose(agent.action_probabilities(x), expected / expected.sum(), rtol=1e-10)


def test_far_state_probabilities_survive_linear_space_underflow() -> None:
    agent = BayesianAgent(D, A)
    assert agent.learn(far_state(D, 0), 1, -60.0, far_state(D, 0)).created
    for m, spread in ((0, 1e-2), (1, 2e-2)):  # concentrated components with light tails
        agent._nu[m], agent._kappa[m] = 600.0, 600.0
        agent._chol[m] = spread * np.eye(D)
        agent._scatter[m] = spread**2 * np.eye(D)
        agent._refresh(m)
    x = far_state(D, 5)
    log_lik = np.array([multivariate_t(loc=mu, shape=(k + 1) / (k * (n - D + 1)) * sc, df=n - D + 1).logpdf(x)
                        for mu, k, n, sc in zip(agent.means, agent.kappa, agent.nu, agent.scatter, strict=True)])
    assert (log_lik < -800).all()  # exp() of every log-density underflows to 0
    p_m_a, p_a, _ = offset_tables(agent.Q)
    expected = p_a * (np.exp(log_lik - log_lik.max()) @ p_m_a)
    probs = agent.action_probabilities(x)
    np.testing.assert_allclose(probs, expected / expected.sum(), rtol=1e-8)
    assert not np.allclose(probs, 1.0 / A)


def test_zero_normaliser_falls_back_to_uniform() -> None:
    agent = BayesianAgent(D, A)
    agent._q[:, :1] = 0.0  # min Q = 0 gives qhat = 0: every Q + qhat entry is 0
    probs = agent.action_probabilities(np.full(D, 1.0 / D))
    np.testing.assert_array_equal(probs, np.full(A, 0.25))
    step = agent.learn(np.full(D, 1.0 / D), 0, 0.0, np.full(D, 1.0 / D))
    assert np.isfinite(step.weight) and np.isfinite(agent.Q).all()


def test_act_greedy_ties_and_tau_policy() -> None:
    agent = BayesianAgent(D, A)
    s = np.full(D, 1.0 / D)
    assert agent.act(s, np.random.default_rng(0), greedy=True) == 0  # all equal: lowest index
    agent._q[2, 0] = 5.0
    assert agent.act(s, np.random.default_rng(0), greedy=True) == 2
    always_greedy = BayesianAgent(D, A, BRLParams(tau_init=1.0))
    always_greedy._q[2, 0] = 5.0
    rng = np.random.default_rng(1)
    assert {always_greedy.act(s, rng) for _ in range(200)} == {2}
    rng = np.random.default_rng(2)
    draws = np.array([agent.act(s, rng) for _ in range(4000)])  # tau = 0.5: 0.625 greedy, 0.125 each other
    freq = np.bincount(draws, minlength=A) / len(draws)
    np.testing.assert_allclose(freq, [0.125, 0.125, 0.625, 0.125], atol=0.03)


# ---------------------------------------------------------------------------------------------------------------
# the learning step: weight cases, creation, schedules
# ---------------------------------------------------------------------------------------------------------------

def two_component_agent() -> BayesianAgent:
    """D = 3, |A| = 2 agent with the initial component and one created at far_state(3, 0)."""
    agent = BayesianAgent(3, 2)
    step = agent.learn(far_state(3, 0), 0, -60.0, far_state(3, 0))
    assert step.created and step.weight_case == "created" and math.isnan(step.weight)
    return agent


@pytest.mark.parametrize(("reward", "state", "case"), [
    (0.0, np.array([0.36, 0.33, 0.31]), "good"),
    (-7.0, np.array([0.36, 0.33, 0.31]), "neutral"),
    (-60.0, np.array([0.36, 0.33, 0.31]), "bad"),  # d_t < rho, so a bad action still updates
    (-60.0, np.array([0.85, 0.10, 0.05]), "bad"),  # near the created component
    (-60.0, np.array([0.05, 0.05, 0.90]), "created"),
])
def test_weight_cases_and_creation_match_oracle(reward: float, state: np.ndarray, case: str) -> None:
    agent = two_component_agent()
    next_state = np.array([0.30, 0.40, 0.30])
    a = 0  # Q[0] = [0.1, -1]: p(m|a) differs between the components, so each weight rule gives its own value
    expected = oracle_step(agent, state, a, reward, next_state)
    assert expected["case"] == case  # the constructed input really exercises this case
    q_before, means_before, kappa_before, alpha = agent.Q, agent.means, agent.kappa, agent.alpha
    step = agent.learn(state, a, reward, next_state)
    assert step.weight_case == case
    assert step.td_error == pytest.approx(expected["td"], rel=1e-12)
    if case == "created":
        assert step.created and step.component == 2 and step.n_components == 3
        np.testing.assert_array_equal(agent.means[2], state)
        assert agent.kappa[2] == 4 and agent.nu[2] == 3
        np.testing.assert_array_equal(agent.scatter[2], 0.1 * np.eye(3))
        np.testing.assert_array_equal(agent.Q[:, 2], np.where(np.arange(2) == a, -1.0, 0.1))
        np.testing.assert_array_equal(agent.Q[:, :2], q_before)
        return
    m = expected["m_t"]
    assert not step.created and step.component == m and step.n_components == 2
    assert 0.0 < expected["w"] < 1.0
    assert step.weight == pytest.approx(expected["w"], rel=1e-9)
    assert agent.Q[a, m] == pytest.approx(q_before[a, m] + alpha * expected["w"] * expected["td"], rel=1e-9)
    kappa = kappa_before[m]
    assert agent.kappa[m] == pytest.approx(kappa + expected["w"], rel=1e-9)
    np.testing.assert_allclose(agent.means[m], means_before[m] + expected["w"] / (kappa + expected["w"])
                               * (state - means_before[m]), rtol=1e-9)


def test_next_action_and_component_selection() -> None:
    agent = BayesianAgent(3, 2)
    assert agent.learn(np.array([0.6, 0.2, 0.2]), 0, -60.0, np.full(3, 1 / 3)).created
    assert agent.learn(np.array([0.2, 0.2, 0.6]), 0, -60.0, np.full(3, 1 / 3)).created
    agent._q[:, :3] = np.array([[-1.0, 5.0, -1.0], [-1.0, -1.0, 9.0]])
    s_t, a_t, s_next = np.array([0.3, 0.3, 0.4]), 0, np.array([0.4, 0.2, 0.4])
    expected = oracle_step(agent, s_t, a_t, -2.0, s_next)
    p_m_a, _, _ = offset_tables(agent.Q)
    # the input separates a' from a_t and argmax p(m|a', s') from argmax p(m|a_t, s'), with different Q
    assert expected["a_next"] == 1 and expected["m_next"] == 2
    assert np.argmax(scipy_densities(agent, s_next) * p_m_a[:, a_t]) == 1
    step = agent.learn(s_t, a_t, -2.0, s_next)
    assert step.td_error == pytest.approx(expected["td"], rel=1e-12)
    assert step.td_error == pytest.approx(-2.0 + 0.9 * 9.0 - (-1.0), rel=1e-12)


def test_thresholds_are_strict() -> None:
    # TD error exactly T_l far from every component: not "> T_l", so a component is created
    zero_q = BayesianAgent(D, A)
    zero_q._q[:, :1] = 0.0  # TD error == reward exactly
    assert zero_q.learn(far_state(D, 0), 0, -10.0, far_state(D, 1)).weight_case == "created"
    zero_q = BayesianAgent(D, A)
    zero_q._q[:, :1] = 0.0
    assert zero_q.learn(far_state(D, 0), 0, -5.0, far_state(D, 1)).weight_case == "neutral"  # == T_u
    # d_t exactly rho: not "< rho", so a bad action creates
    s = far_state(D, 3)
    d = float(np.abs(s - 1.0 / D).max())
    agent = BayesianAgent(D, A, BRLParams(rho_init=d))
    assert agent.learn(s, 0, -60.0, s).created
    agent = BayesianAgent(D, A, BRLParams(rho_init=np.nextafter(d, 1.0)))
    assert agent.learn(s, 0, -60.0, s).weight_case == "bad"


def test_bad_case_with_single_component_has_weight_one() -> None:
    agent = BayesianAgent(D, A)
    s = np.full(D, 1.0 / D) + np.r_[0.01, -0.01, np.zeros(D - 2)]  # within rho of the only component
    step = agent.learn(s, 1, -60.0, s)
    assert step.weight_case == "bad" and step.weight == 1.0
    expected_td = -60.0 + 0.9 * 0.1 - 0.1
    assert step.td_error == pytest.approx(expected_td, rel=1e-14)
    assert agent.Q[1, 0] == pytest.approx(0.1 + 0.99 * expected_td, rel=1e-14)
    assert agent.kappa[0] == D + 2 and agent.nu[0] == D + 1


def test_far_bad_action_creates_component_at_s_t() -> None:
    agent = BayesianAgent(D, A)
    s, s2 = far_state(D, 4), far_state(D, 7)
    step = agent.learn(s, 3, -60.0, s2)
    assert step.created and agent.n_components == 2
    np.testing.assert_array_equal(agent.means[1], s)  # s_t, not s_{t+1}
    np.testing.assert_array_equal(agent.Q[:, 1], [0.1, 0.1, 0.1, -1.0])
    np.testing.assert_array_equal(agent.kappa, [D + 1, D + 1])
    np.testing.assert_array_equal(agent.nu, [D, D])


def test_new_q_nearest_copies_m_t_and_takes_the_td_target() -> None:
    agent = BayesianAgent(D, A, BRLParams(new_q="nearest"))
    agent.learn(np.full(D, 1.0 / D), 2, -3.0, np.full(D, 1.0 / D))  # near: updates component 0's Q[2]
    q0 = agent.Q[:, 0].copy()
    s, s2 = far_state(D, 4), far_state(D, 7)
    step = agent.learn(s, 3, -60.0, s2)
    assert step.created and agent.n_components == 2
    expected = q0.copy()
    expected[3] = -60.0 + 0.9 * q0.max()  # r + gamma Q[a', m']: one component, a' its best action
    assert step.td_error == pytest.approx(expected[3] - q0[3], rel=1e-14)
    np.testing.assert_allclose(agent.Q[:, 1], expected, rtol=1e-14)
    np.testing.assert_array_equal(agent.Q[:, 0], q0)  # m_t itself is not updated on creation
    with pytest.raises(ValueError, match="new_q"):
        BRLParams(new_q="inherit")


def test_visit_count_step_size_averages_a_components_td_targets() -> None:
    agent = BayesianAgent(D, A, BRLParams(step_size="visits"))
    s = np.full(D, 1.0 / D) + np.r_[0.01, -0.01, np.zeros(D - 2)]  # within rho of the only component
    first = agent.learn(s, 1, -60.0, s)
    assert first.weight == 1.0 and agent.kappa[0] == D + 2
    q_after_first = 0.1 + 0.99 * first.td_error  # kappa - D = 1 before it: the schedule's alpha applies
    assert agent.Q[1, 0] == pytest.approx(q_after_first, rel=1e-14)
    second = agent.learn(s, 1, -60.0, s)
    assert second.weight == 1.0
    assert agent.Q[1, 0] == pytest.approx(q_after_first + 0.5 * second.td_error, rel=1e-14)  # 1 / (kappa - D)
    with pytest.raises(ValueError, match="step_size"):
        BRLParams(step_size="adaptive")


def test_action_visit_step_size_averages_each_actions_own_td_targets() -> None:
    agent = BayesianAgent(D, A, BRLParams(step_size="action-visits", alpha_init=1.0, alpha_rate=0.0, gamma=0.0))
    s = np.full(D, 1.0 / D) + np.r_[0.01, -0.01, np.zeros(D - 2)]  # within rho of the only component
    for r in (-20.0, -10.0, -30.0):
        agent.learn(s, 1, r, s)
    agent.learn(s, 2, -4.0, s)  # another action of the same component: its own count, so step 1
    assert agent.Q[1, 0] == pytest.approx(-20.0, rel=1e-14)  # mean of its three targets (gamma 0)
    assert agent.Q[2, 0] == pytest.approx(-4.0, rel=1e-14)  # component-wide counts would give step 1/4
    assert agent.Q[0, 0] == 0.1 and agent.Q[3, 0] == 0.1
    np.testing.assert_array_equal(agent.visits, [[0.0], [3.0], [1.0], [0.0]])


def test_schedules_follow_exponential_approach() -> None:
    params = BRLParams(alpha_rate=0.05, tau_rate=0.2, rho_rate=0.1, alpha_final=0.3, tau_final=0.9, rho_final=0.02)
    agent = BayesianAgent(D, A, params)
    alpha, tau, rho = 0.99, 0.5, 0.1
    rng = np.random.default_rng(7)
    for _ in range(6):
        agent.learn(rng.dirichlet(np.ones(D)), 0, -1.0, rng.dirichlet(np.ones(D)))
        alpha += 0.05 * (0.3 - alpha)
        tau += 0.2 * (0.9 - tau)
        rho += 0.1 * (0.02 - rho)
        assert (agent.alpha, agent.tau, agent.rho) == pytest.approx((alpha, tau, rho), rel=1e-14)
    assert agent.steps == 6
    default = BayesianAgent(D, A)
    for _ in range(3):
        default.learn(np.full(D, 1.0 / D), 0, 0.0, np.full(D, 1.0 / D))
    assert default.tau == pytest.approx(0.99 - 0.49 * (1 - 7e-3) ** 3, rel=1e-14)
    assert default.alpha == pytest.approx(0.01 + 0.98 * (1 - 1e-5) ** 3, rel=1e-14)
    assert default.rho == pytest.approx(0.01 + 0.09 * (1 - 3e-7) ** 3, rel=1e-14)


# ---------------------------------------------------------------------------------------------------------------
# reference-code variant
# ---------------------------------------------------------------------------------------------------------------

def test_reference_code_parameters() -> None:
    ref = BRLParams.reference_code()
    assert (ref.gamma, ref.rho_rate, ref.alpha_rate, ref.variant) == (0.8, 3e-5, 0.0, "reference-code")
    assert BRLParams.reference_code(max_components=50).max_components == 50
    agent = BayesianAgent(D, A, ref)
    for _ in range(5):
        agent.learn(np.full(D, 1.0 / D), 0, -1.0, np.full(D, 1.0 / D))
    assert agent.alpha == 0.99


def test_reference_code_normalises_over_actions() -> None:
    paper = BayesianAgent(3, 3)
    ref = BayesianAgent(3, 3, replace(BRLParams(), variant="reference-code"))
    q = np.array([[0.3, -2.0], [0.1, 0.5], [2.0, 0.0]])
    for agent in (paper, ref):
        agent.learn(far_state(3, 0), 1, -60.0, far_state(3, 0))
        agent._q[:, :2] = q
    p_paper, _, _ = paper._probability_tables()
    p_ref, _, _ = ref._probability_tables()
    shifted = q.T + (2.0 / 3.0 + 2.0)  # qhat for min Q = -2
    np.testing.assert_allclose(p_paper, shifted / shifted.sum(axis=0, keepdims=True), rtol=1e-12)
    np.testing.assert_allclose(p_ref, shifted / shifted.sum(axis=1, keepdims=True), rtol=1e-12)
    x = np.array([0.5, 0.3, 0.2])
    assert not np.allclose(paper.action_probabilities(x), ref.action_probabilities(x), rtol=1e-3)


@pytest.mark.parametrize("variant", ["paper", "reference-code"])
def test_td_error_component_per_variant(variant: str) -> None:
    # From s_t = 0 the initial component (mean 1/3) is l_inf-nearest (1/3 < 0.45), but (0.45, 0, 0) is nearer
    # in l2, so it has the higher density and (with these Q) the higher p(m | a_t, s_t).
    agent = BayesianAgent(3, 2, BRLParams(variant=variant))
    assert agent.learn(np.array([0.45, 0.0, 0.0]), 1, -60.0, np.array([0.45, 0.0, 0.0])).created
    agent._q[:, :2] = np.array([[0.3, 0.6], [0.5, -0.6]])
    q = agent.Q
    s_t, a_t, r, s_next = np.zeros(3), 0, -3.0, np.array([0.3, 0.3, 0.4])
    shifted = q.T + (0.6 / 1.6 + 0.6)
    p_m_a = shifted / shifted.sum(axis=0) if variant == "paper" else shifted / shifted.sum(axis=1, keepdims=True)
    p_a = shifted.sum(axis=0) / shifted.sum()
    lik_next = scipy_densities(agent, s_next)
    a_next = int(np.argmax(p_a * (lik_next @ p_m_a)))
    m_next = int(np.argmax(lik_next * p_m_a[:, a_next]))
    most_probable = int(np.argmax(scipy_densities(agent, s_t) * p_m_a[:, a_t]))
    assert most_probable == 1
    m_delta = 0 if variant == "paper" else most_probable
    step = agent.learn(s_t, a_t, r, s_next)
    assert step.td_error == pytest.approx(r + agent.params.gamma * q[a_next, m_next] - q[a_t, m_delta], rel=1e-12)
    assert step.component == 0  # both variants update the l_inf-nearest component


@pytest.mark.parametrize("variant", ["paper", "reference-code"])
@pytest.mark.parametrize(("new_q", "step_size"), [("constant", "schedule"), ("nearest", "action-visits"),
                                                  ("nearest", "visits")])
@pytest.mark.parametrize(("max_components", "at_capacity"), [(2000, "merge"), (20, "merge"), (20, "skip")])
def test_learning_every_action_at_once_equals_one_learn_call_per_action(variant: str, new_q: str, step_size: str,
                                                                        max_components: int,
                                                                        at_capacity: str) -> None:
    params = BRLParams(variant=variant, new_q=new_q, step_size=step_size, max_components=max_components,
                       at_capacity=at_capacity, init_scatter=0.001)
    one, every = BayesianAgent(D, 6, params), BayesianAgent(D, 6, params)
    rng = np.random.default_rng(3)
    states = rng.dirichlet(np.full(D, 0.2), size=40)
    for i in range(160):  # repeated states (cache hits), creations, capacity growth and the cap
        s = states[int(rng.integers(len(states)))]
        rewards = -20.0 * rng.choice([0.0, 0.05, 0.4, 2.0], size=6)  # the teacher's: 0 for the label
        for a in range(6):
            one.learn(s, a, float(rewards[a]), s, next_value=0.0)
        every.learn_every_action(s, rewards)
        if i % 40 == 39:
            assert_agents_identical(one, every)
    assert_agents_identical(one, every)
    assert one.n_components == 20 if max_components == 20 else one.n_components > 16  # the cap; past 16 slots
    assert np.array_equal(one.action_probabilities(states[0]), every.action_probabilities(states[0]))
    with pytest.raises(ValueError, match="rewards must be 6 finite numbers"):
        every.learn_every_action(states[0], np.zeros(5))


@pytest.mark.parametrize("reference_code", [False, True])
def test_decide_without_the_next_state_equals_the_full_step(reference_code: bool) -> None:
    from brlcli.agent import _kernels

    rng = np.random.default_rng(4)
    n, n_act = 50, 5
    for _ in range(30):
        q = rng.normal(-3.0, 4.0, size=(n_act, n + 3))
        pma, _, p_m = _kernels.tables(q, n, reference_code)
        for a_t in range(n_act):
            col, p_m_col = _kernels._taken_column(q, n, a_t, reference_code)
            assert np.array_equal(col, pma[:, a_t]) and np.array_equal(p_m_col, p_m)
        ll = rng.normal(-5.0, 20.0, size=(2, n + 3))
        dist = rng.uniform(0.0, 1.0, size=(2, n + 3))
        a_t, reward = int(rng.integers(n_act)), float(rng.uniform(-30.0, 5.0))
        # gamma 1e-300 takes the full step (a', m') and adds nothing a reward of this size can hold
        fast = _kernels.decide(ll, dist, 0, 1, q, n, a_t, reward, 0.0, -10.0, -5.0, reference_code)
        full = _kernels.decide(ll, dist, 0, 1, q, n, a_t, reward, 1e-300, -10.0, -5.0, reference_code)
        assert fast == full
    # a reward of -0.0 takes the full step: -0.0 + 0 Q[a', m'] is +0.0 where Q[a', m'] >= 0
    q = np.zeros((n_act, n + 3))
    td = _kernels.decide(ll, dist, 0, 1, q, n, 0, -0.0, 0.0, -10.0, -5.0, reference_code)[0]
    assert td == 0.0 and math.copysign(1.0, td) == 1.0


# ---------------------------------------------------------------------------------------------------------------
# capacity
# ---------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("policy", ["merge", "skip"])
def test_capacity_bound_never_crashes_or_exceeds(policy: str) -> None:
    agent = BayesianAgent(D, A, BRLParams(max_components=3, at_capacity=policy))
    cases = []
    for hot in range(12):
        before = (agent.means, agent.Q)
        step = agent.learn(far_state(D, hot), hot % A, -60.0, far_state(D, (hot + 1) % D))
        assert agent.n_components <= 3 and step.n_components == agent.n_components
        cases.append(step.weight_case)
        if step.weight_case == "capacity":
            assert not step.created
            if policy == "skip":
                assert step.weight == 0.0
                np.testing.assert_array_equal(agent.means, before[0])
                np.testing.assert_array_equal(agent.Q, before[1])
            else:
                assert step.weight > 0.0
                assert not np.array_equal(agent.means[step.component], before[0][step.component])
    assert cases[:2] == ["created", "created"] and "created" not in cases[2:]
    # skip never changes Q, so the TD error stays below T_l; merging lowers Q until updates take over
    assert cases[2:] == ["capacity"] * 10 if policy == "skip" else cases[2:7] == ["capacity"] * 5
    assert np.isfinite(agent.scatter).all() and np.isfinite(agent.Q).all()


def test_storage_grows_and_keeps_components() -> None:
    agent = BayesianAgent(D, A, BRLParams(max_components=40))
    first_means = []
    for hot in range(D):
        agent.learn(far_state(D, hot), 0, -60.0, far_state(D, hot))
        first_means.append(far_state(D, hot))
    assert agent.n_components == D + 1 and agent._capacity() == 32
    np.testing.assert_array_equal(agent.means[1:], np.array(first_means))
    np.testing.assert_array_equal(agent.means[0], np.full(D, 1.0 / D))


# ---------------------------------------------------------------------------------------------------------------
# persistence, determinism, robustness
# ---------------------------------------------------------------------------------------------------------------

def test_save_load_round_trip_and_identical_continuation(tmp_path: os.PathLike) -> None:
    agent = trained_agent(n_steps=80)
    path = os.path.join(tmp_path, "model.npz")
    agent.save(path)
    assert os.listdir(tmp_path) == ["model.npz"]  # no temp file left behind
    loaded = BayesianAgent.load(path)
    assert_agents_identical(agent, loaded)
    rng = np.random.default_rng(11)
    for _ in range(40):
        s, s2 = rng.dirichlet(np.full(D, 0.3)), rng.dirichlet(np.full(D, 0.3))
        a, r = int(rng.integers(A)), float(rng.uniform(-60, 5))
        assert same_step(agent.learn(s, a, r, s2), loaded.learn(s, a, r, s2))
    assert_agents_identical(agent, loaded)


def _rewrite(src: str, dst: str, **changes: object) -> None:
    with np.load(src, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    data.update(changes)
    np.savez(dst, **data)


def test_load_rejects_bad_files(tmp_path: os.PathLike) -> None:
    good = os.path.join(tmp_path, "good.npz")
    BayesianAgent(D, A).save(good)

    wrong_version = os.path.join(tmp_path, "v7.npz")
    _rewrite(good, wrong_version, format_version=np.array(7))
    with pytest.raises(BrlInputError, match="has format version 7, this brl reads 1"):
        BayesianAgent.load(wrong_version)

    text = os.path.join(tmp_path, "notes.npz")
    with open(text, "w") as fh:
        fh.write("not a model\n")
    with pytest.raises(BrlInputError, match="not a brl model"):
        BayesianAgent.load(text)

    pickled = os.path.join(tmp_path, "pickled.npz")
    _rewrite(good, pickled, Q=np.array([{"evil": 1}], dtype=object))
    with pytest.raises(BrlInputError, match="pickled object array 'Q'"):
        BayesianAgent.load(pickled)

    bad_shape = os.path.join(tmp_path, "shape.npz")
    _rewrite(good, bad_shape, Q=np.zeros((A + 1, 1)))
    with pytest.raises(BrlInputError, match="'Q' has shape"):
        BayesianAgent.load(bad_shape)

    bad_visits = os.path.join(tmp_path, "visits.npz")
    _rewrite(good, bad_visits, visits=-np.ones((A, 1)))
    with pytest.raises(BrlInputError, match="'visits' must be"):
        BayesianAgent.load(bad_visits)
    older = os.path.join(tmp_path, "older.npz")  # written before the counts were stored: zeros
    with np.load(good, allow_pickle=False) as npz:
        np.savez(older, **{k: npz[k] for k in npz.files if k != "visits"})
    assert not BayesianAgent.load(older).visits.any()

    truncated = os.path.join(tmp_path, "truncated.npz")
    with open(good, "rb") as fh:
        blob = fh.read()
    with open(truncated, "wb") as fh:
        fh.write(blob[: len(blob) // 2])
    with pytest.raises(BrlInputError):
        BayesianAgent.load(truncated)

    with pytest.raises(BrlInputError, match="does not exist"):
        BayesianAgent.load(os.path.join(tmp_path, "missing.npz"))
    with pytest.raises(BrlInputError, match="does not exist"):
        BayesianAgent(D, A).save(os.path.join(tmp_path, "no-such-dir", "model.npz"))

    npy = os.path.join(tmp_path, "array.npy")
    np.save(npy, np.zeros(3))
    with pytest.raises(BrlInputError, match=r"single \.npy array"):
        BayesianAgent.load(npy)

    for path in (wrong_version, text, pickled, bad_shape, truncated):
        with pytest.raises(BrlInputError) as excinfo:
            BayesianAgent.load(path)
        assert "\n" not in str(excinfo.value) and path in str(excinfo.value)


def test_a_deployment_copy_decides_as_the_model_and_refuses_to_learn(tmp_path: os.PathLike) -> None:
    agent = trained_agent(n_steps=150, seed=4)
    full, copy = os.path.join(tmp_path, "full.npz"), os.path.join(tmp_path, "deploy.npz")
    agent.save(full)
    save_model_arrays(copy, deployment_arrays(agent.to_arrays()))
    assert os.path.getsize(copy) < 0.75 * os.path.getsize(full)
    loaded = BayesianAgent.load(copy)
    assert loaded.deployment and not agent.deployment
    for name in ("Q", "visits", "means", "kappa", "nu", "chol"):
        assert np.array_equal(getattr(agent, name), getattr(loaded, name)), name
    rng = np.random.default_rng(21)
    for _ in range(30):
        s = rng.dirichlet(np.full(D, 0.3))
        assert np.array_equal(agent.action_probabilities(s), loaded.action_probabilities(s))
        assert agent.value(s) == loaded.value(s)
        assert agent.act(s, np.random.default_rng(3)) == loaded.act(s, np.random.default_rng(3))
    with pytest.raises(BrlInputError, match=r"deployment copy .* can drive but not learn"):
        loaded.learn(s, 0, -1.0, s)
    with pytest.raises(BrlInputError, match="no scatter matrices"):
        _ = loaded.scatter
    again = os.path.join(tmp_path, "again.npz")  # a deployment copy saves as one
    loaded.save(again)
    with np.load(copy, allow_pickle=False) as a, np.load(again, allow_pickle=False) as b:
        assert sorted(a.files) == sorted(b.files) and "scatter" not in a.files and int(a["deployment"]) == 1
        assert all(a[k].tobytes() == b[k].tobytes() for k in a.files)

    no_scatter = os.path.join(tmp_path, "no_scatter.npz")  # scatter lost without the marker: refused
    with np.load(full, allow_pickle=False) as npz:
        np.savez(no_scatter, **{k: npz[k] for k in npz.files if k != "scatter"})
    with pytest.raises(BrlInputError, match="lacks the entry 'scatter'"):
        BayesianAgent.load(no_scatter)
    both = os.path.join(tmp_path, "both.npz")  # a marker beside the scatter: refused
    _rewrite(full, both, deployment=np.array(1))
    with pytest.raises(BrlInputError, match="'deployment' must be 1 and come without 'scatter'"):
        BayesianAgent.load(both)


def test_determinism_two_agents_same_sequence() -> None:
    x, y = trained_agent(n_steps=150, seed=9), trained_agent(n_steps=150, seed=9)
    assert_agents_identical(x, y)
    s = np.random.default_rng(0).dirichlet(np.ones(D))
    assert [x.act(s, np.random.default_rng(5)) for _ in range(5)] == [y.act(s, np.random.default_rng(5))
                                                                      for _ in range(5)]


def test_no_nan_after_500_random_steps() -> None:
    rng = np.random.default_rng(12)
    agent = BayesianAgent(D, A)
    for _ in range(500):
        s, s2 = rng.dirichlet(np.full(D, 0.3)), rng.dirichlet(np.full(D, 0.3))
        step = agent.learn(s, int(rng.integers(A)), float(rng.uniform(-60, 5)), s2)
        assert math.isfinite(step.td_error)
        assert step.created or math.isfinite(step.weight)
    for arr in (agent.Q, agent.means, agent.kappa, agent.nu, agent.scatter, agent.chol):
        assert np.isfinite(arr).all()
    assert np.isfinite(log_likelihoods(agent, s)).all()
    assert np.isfinite(agent.action_probabilities(s)).all()
    assert agent.n_components > 5


# ---------------------------------------------------------------------------------------------------------------
# parameters and input validation
# ---------------------------------------------------------------------------------------------------------------

def test_params_defaults_validation_and_dict_round_trip() -> None:
    p = BRLParams()
    assert (p.gamma, p.alpha_init, p.alpha_rate, p.alpha_final) == (0.9, 0.99, 1e-5, 0.01)
    assert (p.tau_init, p.tau_rate, p.tau_final) == (0.5, 7e-3, 0.99)
    assert (p.rho_init, p.rho_rate, p.rho_final, p.T_l, p.T_u) == (0.1, 3e-7, 0.01, -10, -5)
    assert BRLParams.from_dict(p.to_dict()) == p
    assert BRLParams.from_dict(BRLParams.reference_code().to_dict()) == BRLParams.reference_code()
    with pytest.raises(ValueError, match="unknown BRLParams key"):
        BRLParams.from_dict({"gamma": 0.9, "gama": 0.8})
    for bad in ({"gamma": 1.5}, {"variant": "other"}, {"at_capacity": "crash"}, {"max_components": 0},
                {"T_l": 0.0, "T_u": -1.0}, {"alpha_init": float("nan")}, {"init_scatter": 0.0},
                {"max_components": 2.5}):
        with pytest.raises(ValueError, match="BRLParams"):
            BRLParams(**bad)


def test_learn_rejects_bad_inputs() -> None:
    agent = BayesianAgent(D, A)
    s = np.full(D, 1.0 / D)
    with pytest.raises(ValueError, match="shape"):
        agent.learn(s[:5], 0, 0.0, s)
    with pytest.raises(ValueError, match="action"):
        agent.learn(s, A, 0.0, s)
    with pytest.raises(ValueError, match="NaN"):
        agent.learn(s, 0, 0.0, np.full(D, np.nan))
    with pytest.raises(ValueError, match="reward"):
        agent.learn(s, 0, float("inf"), s)
    assert agent.steps == 0


def test_model_files_of_retired_knobs_are_refused_and_their_off_values_read(tmp_path: os.PathLike) -> None:
    """An older brl wrote exploration / td_error / posterior_scale into every model's params_json: at their off
    values the file reads as before; a model trained with one of them is refused with the commit that reads it."""
    import json

    from brlcli.agent.bayes import save_model_arrays
    from brlcli.retired import RETIRED_AT

    agent = BayesianAgent(D, A)
    arrays = agent.to_arrays()
    old = {**agent.params.to_dict(), "exploration": "tau", "td_error": "component", "posterior_scale": 5.0}
    save_model_arrays(os.path.join(tmp_path, "old.npz"), {**arrays, "params_json": np.array(json.dumps(old))})
    assert BayesianAgent.load(os.path.join(tmp_path, "old.npz")).params == agent.params
    posterior = {**old, "exploration": "posterior"}
    save_model_arrays(os.path.join(tmp_path, "p.npz"), {**arrays, "params_json": np.array(json.dumps(posterior))})
    with pytest.raises(BrlInputError, match=f"p.npz was made with exploration = 'posterior'.*{RETIRED_AT}"):
        BayesianAgent.load(os.path.join(tmp_path, "p.npz"))
    save_model_arrays(os.path.join(tmp_path, "b.npz"), {**arrays, "blocks": np.array(4)})
    with pytest.raises(BrlInputError, match=r"shared mixture.*retired"):
        BayesianAgent.load(os.path.join(tmp_path, "b.npz"))
