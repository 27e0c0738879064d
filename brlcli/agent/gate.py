"""The brake gate (issue 35; outside the paper): a Bayesian agent that decides only whether to stop.

A navigation model trained on empty roads (a command-conditioned agent or a committee of them: the *driver*) keeps
its lane and takes its turns; it never learned to stop, and a `stop` primitive among its own actions makes greedy
navigation models stand still (docs/navigation-study.md, section 12.4: standing leaves the camera state unchanged, so
a state where `stop` is greedy is absorbing). The gate is a second `BayesianAgent` with two actions, go and stop,
over the road-user entries of the state (GATE_STATE), learned with Algorithm 1 in traffic on the hazard reward while
the frozen driver drives: at each decision the gate chooses; go takes the driver's greedy action, stop takes the
`stop` primitive (the action index after the driver's).

Model file: one `.npz` with `format_version`, `kind = "brake-gated"`, `gate_state` (GATE_STATE), the driver's
arrays under `driver.` (its own kind and version inside) and the gate's `BayesianAgent` arrays under `gate.`.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from brlcli.agent.bayes import BayesianAgent, LearnStep, Prefixed, _one_line, open_model_npz, save_model_arrays
from brlcli.agent.command import GATED_KIND, CommandAgent, CommitteeAgent, driver_from_npz
from brlcli.agent.params import BRLParams
from brlcli.errors import BrlInputError
from brlcli.features import DYNAMIC_CATEGORY, N_CATEGORIES, N_REGIONS, STATE_DIM
from brlcli.retired import RETIRED_CONFIG, retired_message

GATED_FORMAT_VERSION = 1
"""Version of a brake-gated model file."""
GO, STOP = 0, 1
"""The gate's two actions."""
GATE_STATE = "road_users"
"""What the gate sees: the road-user entries of the driver's state (the dynamic-object share of each of the six image
regions, and any numbers a state option appends): 6 numbers for the paper's state. On the driver's whole state the
gate stood where nothing was near, and the driver's proposed steering beside the road users did not help
(`gate_state`, retired: docs/navigation-study.md section 12.6)."""


def gate_features(state: np.ndarray) -> np.ndarray:
    """The gate's view of an agent state: its road-user entries (GATE_STATE)."""
    return np.concatenate([state[:STATE_DIM].reshape(N_REGIONS, N_CATEGORIES)[:, DYNAMIC_CATEGORY],
                           state[STATE_DIM:]])


class BrakeGatedAgent:
    """A frozen navigation driver and a two-action Bayesian gate (go / stop) that learns when to stop."""

    def __init__(self, driver: CommandAgent | CommitteeAgent, gate: BayesianAgent | None = None,
                 params: BRLParams | None = None) -> None:
        self.driver = driver
        dim = len(gate_features(np.zeros(driver.state_dim)))
        self.gate = gate if gate is not None else BayesianAgent(dim, 2, params)
        if self.gate.state_dim != dim or self.gate.n_actions != 2:
            raise ValueError(f"a brake gate sees {dim} numbers and has two actions, got {self.gate.state_dim} and "
                             f"{self.gate.n_actions}")
        self._rng = np.random.default_rng(0)  # the driver acts greedily: it never draws

    @property
    def state_dim(self) -> int:
        """Length of the state vector."""
        return self.driver.state_dim

    @property
    def n_actions(self) -> int:
        """The driver's primitives and `stop` (the last index)."""
        return self.driver.n_actions + 1

    @property
    def stop_action(self) -> int:
        """The index of the `stop` primitive in the combined action set."""
        return self.driver.n_actions

    @property
    def total_components(self) -> int:
        """The gate's components (the frozen driver's are not learned here)."""
        return self.gate.n_components

    @property
    def components_per_branch(self) -> list[int]:
        """The gate's components, as one branch."""
        return [self.gate.n_components]

    def branch(self, command: int) -> BayesianAgent:
        """The learning agent, whatever the command: the gate."""
        return self.gate

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator, greedy: bool = False) -> int:
        """The gate's behaviour (or greedy) choice: `stop`, or the driver's greedy action under the command."""
        if self.gate.act(gate_features(state), rng, greedy=greedy) == STOP:
            return self.stop_action
        return self.driver.act(state, command, self._rng, greedy=True)

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray, command: int,
              next_command: int) -> LearnStep:
        """One step of Algorithm 1 in the gate on (s_t, go or stop, r_t, s_{t+1}); the driver stays frozen."""
        return self.gate.learn(gate_features(state), STOP if action == self.stop_action else GO, reward,
                               gate_features(next_state))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Format version, kind, the driver's arrays under `driver.` and the gate's under `gate.`."""
        arrays: dict[str, np.ndarray] = {"format_version": np.array(GATED_FORMAT_VERSION, dtype=np.int64),
                                         "kind": np.array(GATED_KIND), "gate_state": np.array(GATE_STATE)}
        arrays.update({f"driver.{k}": v for k, v in self.driver.to_arrays().items()})
        arrays.update({f"gate.{k}": v for k, v in self.gate.to_arrays().items()})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write driver and gate into one versioned .npz, atomically."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> BrakeGatedAgent:
        """Read a model written by `save` (BrlInputError for another kind, version or a corrupt file)."""
        path = os.fspath(path)
        with open_model_npz(path) as npz:
            return cls._from_npz(npz, path)

    @classmethod
    def _from_npz(cls, npz: Any, path: str) -> BrakeGatedAgent:
        """Validate the arrays of an open brake-gated .npz and build the agent."""
        try:
            kind, version, gate_state = str(npz["kind"]), int(npz["format_version"]), str(npz["gate_state"])
        except (KeyError, ValueError, TypeError) as exc:
            raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None
        if kind != GATED_KIND:
            raise BrlInputError(f"model file {path} is a '{kind}' model, not a brake-gated one")
        if version != GATED_FORMAT_VERSION:
            raise BrlInputError(f"model file {path} has format version {version}, this brl reads brake-gated "
                                f"version {GATED_FORMAT_VERSION}")
        if gate_state != GATE_STATE:
            raise BrlInputError(f"model file {path} has a gate on the '{gate_state}' state: "
                                f"{retired_message('gate_state', RETIRED_CONFIG['gate_state'])}")
        if "gate_scale" in npz.files and float(npz["gate_scale"]) != 1.0:
            raise BrlInputError(f"model file {path} has a gate on scaled road-user shares: "
                                f"{retired_message('gate_scale', RETIRED_CONFIG['gate_scale'])}")
        driver = driver_from_npz(Prefixed(npz, "driver."), f"{path} (driver)")
        part = Prefixed(npz, "gate.")
        if "kind" in part.files:  # a gate per route command
            raise BrlInputError(f"model file {path} has a brake gate per route command: "
                                f"{retired_message('gate_branches', RETIRED_CONFIG['gate_branches'])}")
        gate = BayesianAgent._from_npz(part, f"{path} (gate)")
        try:
            return cls(driver, gate)
        except ValueError as exc:
            raise BrlInputError(f"model file {path}: {exc}") from None
