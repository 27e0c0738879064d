"""The Bayesian RL agent of Gharaee et al. (ICPR 2020, Section III), after Firouzi et al. (2012).

Where each paper equation lives (the details the paper leaves open: docs/method.md):

- p(s|m), the NIW posterior predictive Student-t with dof nu' = nu - D + 1 and scale
  Sigma = (kappa + 1) / (kappa nu') S: `student_t_logpdf` (stateless, numpy) and, on the hot path,
  `_kernels.evaluate` (all components in one compiled pass), exposed as `log_likelihoods(agent, state)`.
  Always in log space.
- eq. 2 (offset qhat), eq. 3 (p(m|a)), eq. 4 (p(a)): `_kernels.tables` (`BayesianAgent._probability_tables`).
- eq. 1 (p(a|s)): `_kernels.action_probs` (`BayesianAgent.action_probabilities`).
- eq. 11 (tau-greedy behaviour policy): `BayesianAgent.act`.
- Algorithm 1 with eqs. 5 (TD error), 6 (a'), 7 (m' via p(m|a',s')), 9 (weight w), 10 (p(m|not a, s)):
  `_kernels.decide`; 8 (Q update), the fractional NIW update (`niw_update`, `chol_rank1_update`,
  `_kernels.niw_absorb`) and component creation: `BayesianAgent.learn`; the schedules
  X <- X + rate (final - X) close each learn() call.

Numerics: densities are log-densities shifted by their maximum before they enter a normalised product
(log-sum-exp); a zero normaliser falls back to the uniform distribution; each component keeps its scatter S,
the Cholesky factor L of S (rank-1 updated) and, as caches refreshed after each change (`_refresh`), L^-1
(packed lower triangle) and the Student-t constants. No Python loop runs over M or D on the hot path.

Speed (issue 11): the hot path is a handful of compiled kernels (`brlcli.agent._kernels`, numba). The
log-likelihoods and l_inf distances of the last two states seen are cached (keyed on the state's bytes) and
patched per component when a component changes, so in the training loop `act(s_t)` reuses the pass `learn`
made for s_t as s_{t+1}, and `learn` reuses the pass `act` made for s_t: one pass over M per step. A patched
entry is bitwise equal to a fresh pass (same kernel code per (state, component) pair), so the cache never
changes a result. The Q-derived tables (eqs. 2-4) cost O(M |A|) and are recomputed per call, so writes to `_q`
are always seen.
"""

from __future__ import annotations

import bisect
import functools
import json
import math
import os
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import gammaln

from brlcli.agent import _kernels
from brlcli.agent.params import BRLParams
from brlcli.errors import BrlInputError
from brlcli.npzio import save_npz
from brlcli.retired import RETIRED_CONFIG, retired_message

FORMAT_VERSION = 1
"""Version of the `.npz` model file written by `BayesianAgent.save`."""

DEPLOYMENT_KEY = "deployment"
"""Marks a deployment copy: a model file without its scatter matrices, which can drive but not learn."""

_INITIAL_CAPACITY = 16
"""Preallocated component slots of a new agent; doubled on demand up to `max_components`."""

WEIGHT_CASES = ("good", "bad", "neutral", "created", "capacity")

_CANNOT_LEARN = ("this model is a deployment copy without its scatter matrices (a shipped model): it can drive but "
                 "not learn; train from the run's own model.npz instead")

_CACHE_ROWS = 2
"""States whose log-likelihoods the agent keeps (s_t and s_{t+1} of the current learning step)."""


@dataclass(frozen=True)
class LearnStep:
    """What one `BayesianAgent.learn` call did."""

    td_error: float
    """delta = r_t + gamma Q[a', m'] - Q[a_t, m_t] (eq. 5)."""
    component: int
    """Index of the component updated, or created."""
    created: bool
    weight: float
    """The weight w applied (eq. 9); nan when a component was created, 0.0 when skipped at capacity."""
    weight_case: str
    """'good' (delta > T_u), 'bad' (delta < T_l), 'neutral', 'created', or 'capacity' (creation refused)."""
    n_components: int
    """Number of components after the step."""
    alpha: float
    """The Q learning rate after the step's schedule update (and tau, rho likewise)."""
    tau: float
    rho: float


# ----------------------------------------------------------------------------------------------------------
# Stateless numerics
# ----------------------------------------------------------------------------------------------------------

def forward_substitution(chol: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve chol @ z = rhs for stacked lower-triangular chol (..., D, D) and rhs (..., D), looping over D only."""
    chol = np.asarray(chol, dtype=float)
    rhs = np.asarray(rhs, dtype=float)
    shape = np.broadcast_shapes(chol.shape[:-1], rhs.shape)
    z = np.array(np.broadcast_to(rhs, shape), dtype=float)
    dim = chol.shape[-1]
    for i in range(dim):
        z[..., i] /= chol[..., i, i]
        if i + 1 < dim:
            z[..., i + 1:] -= chol[..., i + 1:, i] * z[..., i, None]
    return z


def student_t_log_normaliser(chol: np.ndarray, kappa: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Per-component log normaliser of St(mu, (kappa+1)/(kappa nu') L L^T, nu'), nu' = nu - D + 1."""
    chol = np.asarray(chol, dtype=float)
    kappa = np.asarray(kappa, dtype=float)
    nu = np.asarray(nu, dtype=float)
    dim = chol.shape[-1]
    dof = nu - dim + 1.0
    scale = (kappa + 1.0) / (kappa * dof)
    log_det_sigma = dim * np.log(scale) + 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(axis=-1)
    return (gammaln(0.5 * (dof + dim)) - gammaln(0.5 * dof) - 0.5 * dim * np.log(dof * np.pi)
            - 0.5 * log_det_sigma)


def student_t_logpdf(states: np.ndarray, means: np.ndarray, chol: np.ndarray, kappa: np.ndarray,
                     nu: np.ndarray) -> np.ndarray:
    """log p(s|m) of states (N, D) or (D,) under M components (chol: Cholesky factors of S): (N, M) or (M,)."""
    states = np.asarray(states, dtype=float)
    means = np.asarray(means, dtype=float)
    kappa = np.asarray(kappa, dtype=float)
    nu = np.asarray(nu, dtype=float)
    single = states.ndim == 1
    states2 = np.atleast_2d(states)
    dim = means.shape[-1]
    dof = nu - dim + 1.0
    inv_scale = kappa * dof / (kappa + 1.0)  # Sigma^-1 = inv_scale * S^-1
    z = forward_substitution(chol, states2[:, None, :] - means[None, :, :])
    maha = np.einsum("nmd,nmd->nm", z, z) * inv_scale
    out = student_t_log_normaliser(chol, kappa, nu) - 0.5 * (dof + dim) * np.log1p(maha / dof)
    return out[0] if single else out


def _work_copy(arr: np.ndarray) -> tuple[np.ndarray, bool]:
    """arr itself when a kernel can write it in place (C-contiguous float64), else a copy; and whether copied."""
    if isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.flags.c_contiguous and arr.flags.writeable:
        return arr, False
    return np.array(arr, dtype=float), True


def chol_rank1_update(chol: np.ndarray, x: np.ndarray) -> None:
    """In place: replace lower-triangular chol (D, D) by the Cholesky factor of chol chol^T + x x^T."""
    work, copied = _work_copy(chol)
    _kernels.chol_rank1(work, np.array(x, dtype=float).reshape(-1))
    if copied:
        chol[...] = work


def niw_update(mean: np.ndarray, kappa: float, nu: float, scatter: np.ndarray, chol: np.ndarray,
               x: np.ndarray, w: float) -> tuple[float, float]:
    """In place: absorb x with fractional count w into (mean, scatter, chol); return the new (kappa, nu)."""
    if not (math.isfinite(w) and w >= 0.0):
        raise ValueError(f"NIW update weight must be finite and >= 0, got {w}")
    if w == 0.0:
        return kappa, nu
    works = [_work_copy(a) for a in (mean, scatter, chol)]
    (m_work, _), (s_work, _), (c_work, _) = works
    _kernels.niw_absorb(m_work, s_work, c_work, np.array(x, dtype=float).reshape(-1), float(w), float(kappa))
    for target, (work, copied) in zip((mean, scatter, chol), works, strict=True):
        if copied:
            target[...] = work
    return kappa + w, nu + w


def _validated_state(state: Any, dim: int, what: str) -> np.ndarray:
    """A finite float vector of length dim, or ValueError."""
    arr = np.asarray(state, dtype=float)
    if arr.shape != (dim,):
        raise ValueError(f"{what} must have shape ({dim},), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} contains NaN or infinity")
    return arr


# ----------------------------------------------------------------------------------------------------------
# The agent
# ----------------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=16)
def _kernel_constants(p: BRLParams) -> tuple[np.ndarray, np.ndarray]:
    """The parameters as `_kernels.learn_every_action` takes them (scalars, codes), built once per parameter set."""
    scalars = np.array([p.gamma, p.T_l, p.T_u, p.alpha_rate, p.alpha_final, p.tau_rate, p.tau_final, p.rho_rate,
                        p.rho_final, p.init_scatter, p.init_q, p.new_q_taken])
    codes = np.array([p.variant != "paper", _kernels.STEP_SIZE_CODES[p.step_size], p.max_components,
                      p.new_q == "nearest", p.at_capacity == "merge"], dtype=np.int64)
    scalars.flags.writeable = codes.flags.writeable = False
    return scalars, codes


class BayesianAgent:
    """Mixture of NIW components with a Q column each; `learn` is Algorithm 1 of the paper."""

    def __init__(self, state_dim: int = 30, n_actions: int = 4, params: BRLParams | None = None) -> None:
        """A fresh model: one component with mean 1/D, nu = D, kappa = D + 1, S = init_scatter I, Q = init_q."""
        if isinstance(state_dim, bool) or not isinstance(state_dim, int | np.integer) or state_dim < 1:
            raise ValueError(f"state_dim must be a positive integer, got {state_dim!r}")
        if isinstance(n_actions, bool) or not isinstance(n_actions, int | np.integer) or n_actions < 1:
            raise ValueError(f"n_actions must be a positive integer, got {n_actions!r}")
        params = BRLParams() if params is None else params
        if not isinstance(params, BRLParams):
            raise ValueError(f"params must be a BRLParams, got {type(params).__name__}")
        self._dim = int(state_dim)
        self._n_actions = int(n_actions)
        self._params = params
        self._alpha = params.alpha_init
        self._tau = params.tau_init
        self._rho = params.rho_init
        self._steps = 0
        self._n = 0
        self._deployment = False
        self._allocate(min(_INITIAL_CAPACITY, params.max_components))
        self._add_component(np.full(self._dim, 1.0 / self._dim))

    # -- storage ---------------------------------------------------------------------------------------------

    def _allocate(self, capacity: int) -> None:
        """(Re)allocate every per-component array with `capacity` slots, keeping the first n components."""
        dim, n = self._dim, self._n
        old = getattr(self, "_mean", None)
        new = {
            "_mean": np.zeros((capacity, dim)),
            "_kappa": np.zeros(capacity),
            "_nu": np.zeros(capacity),
            "_scatter": np.zeros((capacity, dim, dim)),
            "_chol": np.zeros((capacity, dim, dim)),
            "_chol_inv_packed": np.zeros((capacity, dim * (dim + 1) // 2)),  # L^-1, lower triangle by rows
            "_t_params": np.tile([0.0, 1.0, 1.0], (capacity, 1)),  # (log normaliser, inv_scale, dof)
        }
        for name, arr in new.items():
            if old is not None and n:
                arr[:n] = getattr(self, name)[:n]
            setattr(self, name, arr)
        for name in ("_q", "_visits"):  # action values and their weighted update counts
            arr = np.zeros((self._n_actions, capacity))
            if old is not None and n:
                arr[:, :n] = getattr(self, name)[:, :n]
            setattr(self, name, arr)
        # likelihood cache: rows of (state, log p(s|m), ||s - mu_m||_inf), always valid for m < n
        self._cache_states = np.zeros((_CACHE_ROWS, dim))
        self._cache_ll = np.zeros((_CACHE_ROWS, capacity))
        self._cache_dist = np.zeros((_CACHE_ROWS, capacity))
        self._cache_keys: list[bytes | None] = [None] * _CACHE_ROWS
        self._cache_last = 0

    def _capacity(self) -> int:
        """Number of preallocated component slots."""
        return self._mean.shape[0]

    def _refresh(self, m: int) -> None:
        """Recompute the cached L^-1 and Student-t constants of component m from (L, kappa, nu); patch the cache."""
        _kernels.refresh(self._chol, self._kappa, self._nu, self._chol_inv_packed, self._t_params, m)
        _kernels.evaluate(self._cache_states, 0, _CACHE_ROWS, self._mean, self._chol_inv_packed, self._t_params,
                          m, m + 1, self._cache_ll, self._cache_dist)

    def _add_component(self, mean: np.ndarray) -> int:
        """Append a component at `mean` (nu = D, kappa = D + 1, S = init_scatter I, Q = init_q); return its index."""
        p = self._params
        if self._n >= self._capacity():
            self._allocate(min(2 * self._capacity(), p.max_components))
        m = self._n
        _kernels.create(m, np.ascontiguousarray(mean, dtype=np.float64), p.init_scatter, p.init_q, self._q,
                        self._visits, self._mean, self._kappa, self._nu, self._scatter, self._chol,
                        self._chol_inv_packed, self._t_params, self._cache_states, self._cache_ll, self._cache_dist)
        self._n = m + 1
        return m

    def _checked(self, state: Any, what: str) -> tuple[np.ndarray, bytes, int]:
        """Validate a state (shape (D,), finite); return it as float64, its cache key and cache row (-1: absent)."""
        arr = state
        if type(arr) is not np.ndarray or arr.dtype != np.float64:
            arr = np.asarray(state, dtype=float)
        if arr.shape != (self._dim,):
            raise ValueError(f"{what} must have shape ({self._dim},), got {arr.shape}")
        key = arr.tobytes()
        keys = self._cache_keys
        row = 0 if keys[0] == key else 1 if keys[1] == key else -1
        if row < 0 and not _kernels.all_finite(np.ascontiguousarray(arr)):  # cached states were checked
            raise ValueError(f"{what} contains NaN or infinity")
        return arr, key, row

    def _cached_row(self, arr: np.ndarray, key: bytes, row: int) -> int:
        """Cache row holding log p(s|m) and the l_inf distances of state arr (computed now if absent)."""
        if row < 0:
            row = 1 - self._cache_last  # the least recently used row
            self._cache_keys[row] = None
            self._cache_states[row] = arr
            _kernels.evaluate(self._cache_states, row, row + 1, self._mean, self._chol_inv_packed, self._t_params,
                              0, self._n, self._cache_ll, self._cache_dist)
            self._cache_keys[row] = key
        self._cache_last = row
        return row

    # -- read-only state -------------------------------------------------------------------------------------

    @property
    def params(self) -> BRLParams:
        """The agent's parameters."""
        return self._params

    @property
    def state_dim(self) -> int:
        """Dimension D of the state vector."""
        return self._dim

    @property
    def n_actions(self) -> int:
        """Number of actions |A|."""
        return self._n_actions

    @property
    def n_components(self) -> int:
        """Number of mixture components M."""
        return self._n

    @property
    def steps(self) -> int:
        """Number of learn() calls so far."""
        return self._steps

    @property
    def alpha(self) -> float:
        """Current Q learning rate."""
        return self._alpha

    @property
    def tau(self) -> float:
        """Current behaviour-policy temperature."""
        return self._tau

    @property
    def rho(self) -> float:
        """Current l_inf distance threshold."""
        return self._rho

    @property
    def Q(self) -> np.ndarray:
        """Copy of the action values, shape (n_actions, M)."""
        return self._q[:, :self._n].copy()

    @property
    def means(self) -> np.ndarray:
        """Copy of the component means, shape (M, D)."""
        return self._mean[:self._n].copy()

    @property
    def kappa(self) -> np.ndarray:
        """Copy of the NIW pseudo-counts kappa, shape (M,)."""
        return self._kappa[:self._n].copy()

    @property
    def nu(self) -> np.ndarray:
        """Copy of the NIW degrees of freedom nu, shape (M,)."""
        return self._nu[:self._n].copy()

    @property
    def deployment(self) -> bool:
        """True for a deployment copy (loaded without its scatter matrices): it drives but cannot learn."""
        return self._deployment

    @property
    def scatter(self) -> np.ndarray:
        """Copy of the scatter matrices S, shape (M, D, D); a deployment copy has none."""
        if self._deployment:
            raise BrlInputError("a deployment copy of a model has no scatter matrices (shipped without them)")
        return self._scatter[:self._n].copy()

    @property
    def chol(self) -> np.ndarray:
        """Copy of the lower Cholesky factors of S, shape (M, D, D)."""
        return self._chol[:self._n].copy()

    # -- probabilities ---------------------------------------------------------------------------------------

    def _log_lik(self, states: np.ndarray) -> np.ndarray:
        """log p(s|m) for states (N, D) and every component in one compiled pass: (N, M)."""
        states = np.array(states, dtype=float, ndmin=2)
        n_states = states.shape[0]
        out = np.empty((n_states, self._n))
        _kernels.evaluate(states, 0, n_states, self._mean, self._chol_inv_packed, self._t_params, 0, self._n, out,
                          np.empty((n_states, self._n)))
        return out

    def _probability_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p(m|a) as (M, A), p(a) as (A,), p(m) as (M,)) from Q + qhat (eqs. 2-4)."""
        # the reference code normalises over actions
        return _kernels.tables(self._q, self._n, self._params.variant != "paper")

    def action_probabilities(self, state: np.ndarray) -> np.ndarray:
        """p(a|s) for every action (eq. 1); sums to 1."""
        row = self._cached_row(*self._checked(state, "state"))
        return _kernels.action_probs(self._cache_ll[row], self._q, self._n, self._params.variant != "paper")

    @property
    def visits(self) -> np.ndarray:
        """Weighted count of updates of each action value, shape (|A|, M) (a copy)."""
        return self._visits[:, :self._n].copy()

    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = False) -> int:
        """Behaviour policy (eq. 11): the greedy action gets (1 - tau)/|A| + tau, the others (1 - tau)/|A|."""
        greedy_action = int(np.argmax(self.action_probabilities(state)))
        if greedy:
            return greedy_action
        n_act = self._n_actions
        base = (1.0 - self._tau) / n_act
        cumulative, total = [], 0.0
        for a in range(n_act):  # the running sum of np.cumsum, over the |A| actions
            total += base + self._tau if a == greedy_action else base
            cumulative.append(total)
        u = rng.random() * total
        return min(bisect.bisect_right(cumulative, u), n_act - 1)

    # -- learning --------------------------------------------------------------------------------------------

    def value(self, state: np.ndarray) -> float:
        """The value Algorithm 1's TD target takes at a state: Q[a', m'] (eqs. 6-7). Another agent's learning step can
        bootstrap from it (`learn(..., next_value=)`)."""
        row = self._cached_row(*self._checked(state, "state"))
        return float(_kernels.next_value(self._cache_ll[row], self._q, self._n, self._params.variant != "paper"))

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray,
              next_value: float | None = None) -> LearnStep:
        """One step of Algorithm 1 on (s_t, a_t, r_t, s_{t+1}); docs/method.md, 'One learning step'.

        With `next_value` the TD target is r_t + gamma * next_value instead of this agent's own value of s_{t+1}
        (the command-conditioned agent, where the next decision belongs to another branch); `next_state` is then
        not read."""
        if self._deployment:
            raise BrlInputError(_CANNOT_LEARN)
        p = self._params
        checked_t = self._checked(state, "state")
        if next_value is not None:
            if not math.isfinite(next_value):
                raise ValueError(f"next_value must be finite, got {next_value}")
            reward_in, gamma = float(reward) + p.gamma * float(next_value), 0.0
            checked_next = checked_t
        else:
            reward_in, gamma = float(reward), p.gamma
            checked_next = self._checked(next_state, "next_state")
        if isinstance(action, bool) or not isinstance(action, int | np.integer) or not 0 <= action < self._n_actions:
            raise ValueError(f"action must be an integer in [0, {self._n_actions}), got {action!r}")
        a_t = int(action)
        reward = float(reward)
        if not math.isfinite(reward):
            raise ValueError(f"reward must be finite, got {reward}")

        row_t = self._cached_row(*checked_t)
        row_next = row_t if checked_next[1] == checked_t[1] else self._cached_row(*checked_next)
        # steps 1-3 and the weight of eq. 9: a', m', m_t, d_t, the TD error (eq. 5) and w for m_t
        td_error, m_t, d_t, weight, case = _kernels.decide(
            self._cache_ll, self._cache_dist, row_t, row_next, self._q, self._n, a_t, reward_in, gamma, p.T_l,
            p.T_u, p.variant != "paper")
        m_t = int(m_t)
        weight = float(weight)
        s_t = self._cache_states[row_t].copy()

        if d_t < self._rho or td_error > p.T_l:
            self._update(m_t, a_t, s_t, td_error, weight)
            step = (m_t, False, weight, WEIGHT_CASES[case])
        elif self._n < p.max_components:
            m_new = self._add_component(s_t)
            if p.new_q == "nearest":  # m_t's action values, the taken action at the value just observed
                self._q[:, m_new] = self._q[:, m_t]
                self._q[a_t, m_new] = self._q[a_t, m_t] + td_error
            else:
                self._q[a_t, m_new] = p.new_q_taken
            step = (m_new, True, math.nan, "created")
        elif p.at_capacity == "merge":
            self._update(m_t, a_t, s_t, td_error, weight)
            step = (m_t, False, weight, "capacity")
        else:  # "skip"
            step = (m_t, False, 0.0, "capacity")

        # 6. schedules
        self._alpha += p.alpha_rate * (p.alpha_final - self._alpha)
        self._tau += p.tau_rate * (p.tau_final - self._tau)
        self._rho += p.rho_rate * (p.rho_final - self._rho)
        self._steps += 1
        return LearnStep(td_error, *step, self._n, self._alpha, self._tau, self._rho)

    def learn_every_action(self, state: np.ndarray, rewards: np.ndarray) -> None:
        """`learn(state, a, rewards[a], state, next_value=0.0)` for every action a in turn, in one compiled call: the
        same model, bit for bit (the imitation fit's inner loop, `brlcli.imitation.fit_mixture`)."""
        if self._deployment:
            raise BrlInputError(_CANNOT_LEARN)
        rewards = np.ascontiguousarray(rewards, dtype=np.float64)
        if rewards.shape != (self._n_actions,) or not _kernels.all_finite(rewards):
            raise ValueError(f"rewards must be {self._n_actions} finite numbers, got {rewards!r}")
        p = self._params
        checked = self._checked(state, "state")
        while self._n + self._n_actions > self._capacity() and self._capacity() < p.max_components:
            self._allocate(min(2 * self._capacity(), p.max_components))  # this clears the likelihood cache
            checked = self._checked(state, "state")
        row_t = self._cached_row(*checked)
        scalars, codes = _kernel_constants(p)
        n, alpha, tau, rho = _kernels.learn_every_action(
            row_t, rewards, self._n, self._alpha, self._tau, self._rho, scalars, codes, self._q, self._visits,
            self._mean, self._kappa, self._nu, self._scatter, self._chol, self._chol_inv_packed, self._t_params,
            self._cache_states, self._cache_ll, self._cache_dist)
        self._n, self._alpha, self._tau, self._rho = int(n), float(alpha), float(tau), float(rho)
        self._steps += self._n_actions

    def _update(self, m: int, a_t: int, s_t: np.ndarray, td_error: float, weight: float) -> None:
        """Q update (eq. 8) and fractional NIW update of component m with weight w."""
        _kernels.absorb(m, a_t, s_t, td_error, weight, self._alpha, _kernels.STEP_SIZE_CODES[self._params.step_size],
                        self._q, self._visits, self._mean, self._kappa, self._nu, self._scatter, self._chol,
                        self._chol_inv_packed, self._t_params, self._cache_states, self._cache_ll, self._cache_dist)

    # -- persistence -----------------------------------------------------------------------------------------

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The model's arrays as `save` writes them (format version, parameters, components, schedules)."""
        if self._deployment:
            return deployment_arrays(self._full_arrays())
        return self._full_arrays()

    def _full_arrays(self) -> dict[str, np.ndarray]:
        """Every array of the model, the scatter matrices included."""
        n = self._n
        return {
            "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
            "params_json": np.array(json.dumps(self._params.to_dict(), sort_keys=True)),
            "state_dim": np.array(self._dim, dtype=np.int64),
            "n_actions": np.array(self._n_actions, dtype=np.int64),
            "means": self._mean[:n],
            "kappa": self._kappa[:n],
            "nu": self._nu[:n],
            "scatter": self._scatter[:n],
            "chol": self._chol[:n],
            "Q": self._q[:, :n],
            "visits": self._visits[:, :n],
            "alpha": np.array(self._alpha),
            "tau": np.array(self._tau),
            "rho": np.array(self._rho),
            "steps": np.array(self._steps, dtype=np.int64),
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model to `path` (exactly that name) as a versioned .npz, atomically via a temp file."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> BayesianAgent:
        """Read a model written by `save`; a missing, foreign, corrupt or wrong-version file raises BrlInputError."""
        path = os.fspath(path)
        npz = open_model_npz(path)
        with npz:
            try:
                return cls._from_npz(npz, path)
            except BrlInputError:
                raise
            except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
                raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None

    @classmethod
    def _from_npz(cls, npz: Any, path: str) -> BayesianAgent:
        """Validate the arrays of an open .npz and build the agent."""

        def get(key: str) -> np.ndarray:
            """The array stored under key (object arrays refused)."""
            if key not in npz.files:
                raise BrlInputError(f"model file {path} lacks the entry '{key}'")
            try:
                return npz[key]
            except ValueError as exc:
                if "allow_pickle" in str(exc):
                    raise BrlInputError(f"model file {path} holds a pickled object array '{key}' "
                                        "(refused: pickles can run code)") from None
                raise

        def scalar(key: str, kind: str) -> Any:
            """The 0-d array under key as a Python scalar, checking its dtype kind."""
            arr = get(key)
            if arr.shape != () or arr.dtype.kind not in kind:
                raise BrlInputError(f"model file {path}: '{key}' must be a scalar of kind {kind!r}, "
                                    f"got shape {arr.shape} dtype {arr.dtype}")
            return arr.item()

        version = scalar("format_version", "iu")
        if version != FORMAT_VERSION:
            raise BrlInputError(f"model file {path} has format version {version}, this brl reads {FORMAT_VERSION}")
        try:
            params = BRLParams.from_dict(json.loads(scalar("params_json", "U")), where=f"model file {path}")
        except (ValueError, TypeError) as exc:
            raise BrlInputError(f"model file {path} has bad parameters: {_one_line(exc)}") from None
        dim, n_actions = scalar("state_dim", "iu"), scalar("n_actions", "iu")
        if dim < 1 or n_actions < 1:
            raise BrlInputError(f"model file {path} has state_dim {dim} and n_actions {n_actions}")
        if "blocks" in npz.files:  # a mixture shared by the commands, with a block of action values per command
            retired = retired_message("shared_mixture", RETIRED_CONFIG["shared_mixture"])
            raise BrlInputError(f"model file {path} has a shared mixture: {retired}")
        rows = n_actions
        means = get("means")
        if means.ndim != 2 or means.shape[1] != dim:
            raise BrlInputError(f"model file {path}: means has shape {means.shape}, expected (M, {dim})")
        n = means.shape[0]
        if not 1 <= n <= params.max_components:
            raise BrlInputError(f"model file {path} has {n} components, expected 1..{params.max_components}")
        deployment = DEPLOYMENT_KEY in npz.files
        if deployment and (scalar(DEPLOYMENT_KEY, "iub") != 1 or "scatter" in npz.files):
            raise BrlInputError(f"model file {path}: '{DEPLOYMENT_KEY}' must be 1 and come without 'scatter'")
        expected = {"means": (n, dim), "kappa": (n,), "nu": (n,), "chol": (n, dim, dim), "Q": (rows, n)}
        if not deployment:
            expected["scatter"] = (n, dim, dim)
        arrays: dict[str, np.ndarray] = {}
        for key, shape in expected.items():
            arr = get(key)
            if arr.shape != shape or arr.dtype != np.float64:
                raise BrlInputError(f"model file {path}: '{key}' has shape {arr.shape} dtype {arr.dtype}, "
                                    f"expected shape {shape} float64")
            if not np.isfinite(arr).all():
                raise BrlInputError(f"model file {path}: '{key}' contains NaN or infinity")
            arrays[key] = arr
        visits = npz["visits"] if "visits" in npz.files else np.zeros((rows, n))  # absent before issue 18
        if visits.shape != (rows, n) or visits.dtype != np.float64 or not np.isfinite(visits).all() \
                or (visits < 0).any():
            raise BrlInputError(f"model file {path}: 'visits' must be finite non-negative float64 of shape "
                                f"{(rows, n)}, got shape {visits.shape} dtype {visits.dtype}")
        chol_diag = np.diagonal(arrays["chol"], axis1=1, axis2=2)
        if (arrays["kappa"] <= 0).any() or (arrays["nu"] <= dim - 1).any() or (chol_diag <= 0).any() \
                or np.triu(arrays["chol"], k=1).any():
            raise BrlInputError(f"model file {path} has an invalid component (kappa <= 0, nu <= D - 1, "
                                "or a Cholesky factor that is not lower-triangular with a positive diagonal)")
        schedule = {key: float(scalar(key, "f")) for key in ("alpha", "tau", "rho")}
        steps = scalar("steps", "iu")
        if not all(math.isfinite(v) for v in schedule.values()) or steps < 0:
            raise BrlInputError(f"model file {path} has invalid schedule values or step count")

        agent = cls(int(dim), int(n_actions), params)
        capacity = min(params.max_components, max(_INITIAL_CAPACITY, 1 << (n - 1).bit_length()))
        agent._n = 0
        agent._allocate(capacity)
        agent._mean[:n] = arrays["means"]
        agent._kappa[:n] = arrays["kappa"]
        agent._nu[:n] = arrays["nu"]
        if deployment:
            agent._deployment = True
        else:
            agent._scatter[:n] = arrays["scatter"]
        agent._chol[:n] = arrays["chol"]
        agent._q[:, :n] = arrays["Q"]
        agent._visits[:, :n] = visits
        agent._n = n
        for m in range(n):  # cold path: the caches, computed exactly as learn() computes them
            agent._refresh(m)
        agent._alpha, agent._tau, agent._steps = schedule["alpha"], schedule["tau"], int(steps)
        agent._rho = schedule["rho"]
        return agent


def deployment_arrays(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A model file's arrays as a deployment copy: every mixture's scatter matrices dropped, a marker in their place.

    Driving reads the Cholesky factors only, so the copy decides exactly as the model (about half the file); it
    cannot learn further. Works on a single mixture's arrays and on prefixed ones (`follow.scatter`, ...)."""
    out: dict[str, np.ndarray] = {}
    for key, value in arrays.items():
        if key == "scatter" or key.endswith(".scatter"):
            out[key[:-len("scatter")] + DEPLOYMENT_KEY] = np.array(1, dtype=np.int64)
        else:
            out[key] = value
    return out


def save_model_arrays(path: str | os.PathLike[str], arrays: dict[str, np.ndarray]) -> None:
    """Write a model's arrays to `path` as an .npz, atomically; a missing directory is a BrlInputError."""
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise BrlInputError(f"cannot write model file {path}: directory {directory} does not exist")
    save_npz(path, arrays)


def open_model_npz(path: str) -> Any:
    """The open .npz of a model file (never unpickling); a missing, foreign or corrupt file is a BrlInputError."""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
        if not (magic.startswith(b"PK") or magic == b"\x93NUMPY"):
            raise BrlInputError(f"model file {path} is not a brl model (.npz): it is not a zip archive")
        npz = np.load(path, allow_pickle=False)
    except IsADirectoryError:
        raise BrlInputError(f"model file {path} is a directory without model.npz or member_<k>/model.npz") from None
    except FileNotFoundError:
        raise BrlInputError(f"model file {path} does not exist") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise BrlInputError(f"model file {path} is not a brl model (.npz): {_one_line(exc)}") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise BrlInputError(f"model file {path} is a single .npy array, not a brl model (.npz)")
    return npz


class Prefixed:
    """The entries of an open .npz under a key prefix, with the `files` / `[]` interface `_from_npz` reads."""

    def __init__(self, npz: Any, prefix: str) -> None:
        self._npz = npz
        self._prefix = prefix
        self.files = [k[len(prefix):] for k in npz.files if k.startswith(prefix)]

    def __getitem__(self, key: str) -> np.ndarray:
        return self._npz[self._prefix + key]


def _one_line(exc: BaseException) -> str:
    """First line of an exception message (or its type name when empty)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def log_likelihoods(agent: BayesianAgent, state: np.ndarray) -> np.ndarray:
    """log p(s|m) of every component of `agent` for one state: shape (M,)."""
    s = _validated_state(state, agent.state_dim, "state")
    return agent._log_lik(s[None, :])[0]
