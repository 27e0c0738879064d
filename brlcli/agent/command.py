"""The command-conditioned Bayesian agent (issue 20; outside the paper): one Bayesian RL agent per route command.

In the spirit of conditional imitation learning's branches, the planner's high-level command (follow lane, left,
right, straight; `brlcli.sim.roadnet.BRANCH_COMMANDS`) selects one of four independent `BayesianAgent`s, each with
the paper's equations (and whatever `BRLParams` the run chose) and its own mixture model, action values and
schedules. The behaviour policy and the greedy action of a decision are those of the branch of the command at that
decision; the learning step (s_t, a_t, r_t, s_{t+1}) goes to the branch of the command at t, Algorithm 1 unchanged
inside it. Where the command changes between t and t+1, the TD target bootstraps from the value of s_{t+1} in the
branch of the command at t+1, the branch that acts there, as Q-learning on the pair (state, command) would
(`BayesianAgent.learn(..., next_value=)`). The agent composes its branches through their public interface and keeps
no state of its own besides them: every call names its command.

`CommitteeAgent` composes K such agents, trained apart, that vote.

Model file: one `.npz` with `format_version`, `kind = "command-conditioned"`, `branches` (the branch names) and,
for each branch, the arrays of `BayesianAgent.save` under the prefix `<branch>.`; a committee's file holds each
member's arrays under `member<k>.`.
"""

from __future__ import annotations

import os
import zipfile
from typing import Any

import numpy as np

from brlcli.agent.bayes import BayesianAgent, LearnStep, Prefixed, _one_line, open_model_npz, save_model_arrays
from brlcli.agent.committee import committee_members, majority_vote, model_file
from brlcli.agent.params import BRLParams
from brlcli.errors import BrlInputError
from brlcli.features import road_user_in_view
from brlcli.retired import RETIRED_CONFIG, retired_message
from brlcli.sim.roadnet import BRANCH_NAMES, command_branch

COMMAND_FORMAT_VERSION = 1
"""Version of the command-conditioned model file."""
RETIRED_FORMAT_VERSIONS = {2: "straight_as_follow", 3: "shared_mixture"}
"""Versions of files that older brl wrote for retired knobs: "go straight" in the follow branch, a shared mixture."""
COMMAND_KIND = "command-conditioned"


class CommandAgent:
    """Four Bayesian RL agents, one per route command (`branch_of`); `act` and `learn` take the command."""

    def __init__(self, state_dim: int = 30, n_actions: int = 4, params: BRLParams | None = None) -> None:
        self.branches = [BayesianAgent(state_dim, n_actions, params) for _ in BRANCH_NAMES]

    @classmethod
    def from_branches(cls, branches: list[BayesianAgent]) -> CommandAgent:
        """An agent made of existing branches (in BRANCH_NAMES order)."""
        if len(branches) != len(BRANCH_NAMES):
            raise ValueError(f"a command-conditioned agent has {len(BRANCH_NAMES)} branches, got {len(branches)}")
        agent = cls.__new__(cls)
        agent.branches = list(branches)
        return agent

    @staticmethod
    def branch_of(command: int) -> int:
        """The branch (index into BRANCH_NAMES) that acts on a CARLA command code (2 follow, 3 left, 4 right,
        5 straight; others follow)."""
        return int(command_branch(int(command)))

    def branch(self, command: int) -> BayesianAgent:
        """The Bayesian agent that acts and learns under a command."""
        return self.branches[self.branch_of(command)]

    def restart_branch(self, branch: int) -> None:
        """Restart one branch from a fresh agent (its per-branch trap restart)."""
        first = self.branches[0]
        self.branches[branch] = BayesianAgent(first.state_dim, first.n_actions, first.params)

    @property
    def state_dim(self) -> int:
        """Length of the state vector."""
        return self.branches[0].state_dim

    @property
    def n_actions(self) -> int:
        """Number of action primitives."""
        return self.branches[0].n_actions

    @property
    def components_per_branch(self) -> list[int]:
        """Components of every branch, in BRANCH_NAMES order."""
        return [b.n_components for b in self.branches]

    @property
    def total_components(self) -> int:
        """Components of the whole agent (the sum over the branches)."""
        return sum(self.components_per_branch)

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator, greedy: bool = False) -> int:
        """The behaviour (or greedy) action of the command's branch for the state."""
        return self.branch(command).act(state, rng, greedy=greedy)

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray, command: int,
              next_command: int) -> LearnStep:
        """One step of Algorithm 1 in the branch of `command`; when `next_command` names another branch, the target
        takes that branch's value of s_{t+1}."""
        here, there = self.branch_of(command), self.branch_of(next_command)
        if there == here:
            return self.branches[here].learn(state, action, reward, next_state)
        value = self.branches[there].value(next_state)
        return self.branches[here].learn(state, action, reward, next_state, next_value=value)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The model's arrays as `save` writes them: format version, kind, branch names, each branch's arrays."""
        arrays: dict[str, np.ndarray] = {"format_version": np.array(COMMAND_FORMAT_VERSION, dtype=np.int64),
                                         "kind": np.array(COMMAND_KIND), "branches": np.array(BRANCH_NAMES)}
        for name, b in zip(BRANCH_NAMES, self.branches, strict=True):
            arrays.update({f"{name}.{k}": v for k, v in b.to_arrays().items()})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write every branch into one versioned .npz, atomically."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CommandAgent:
        """Read a model written by `save`; a lane-keeping model, a foreign or corrupt file raise BrlInputError."""
        path = os.fspath(path)
        npz = open_model_npz(path)
        with npz:
            return cls._from_npz(npz, path)

    @classmethod
    def _from_npz(cls, npz: Any, path: str) -> CommandAgent:
        """Validate the arrays of an open .npz (or a prefixed view of one) and build the agent."""
        if "kind" not in npz.files:
            raise BrlInputError(f"model file {path} is a lane-keeping model, not a command-conditioned one")
        try:
            kind = str(npz["kind"])
        except ValueError as exc:
            raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None
        if kind != COMMAND_KIND:
            raise BrlInputError(f"model file {path} is a '{kind}' model, not a command-conditioned one")
        try:
            version = int(npz["format_version"])
            names = [str(n) for n in npz["branches"]]
        except (KeyError, ValueError, TypeError) as exc:
            raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None
        if version in RETIRED_FORMAT_VERSIONS:
            knob = RETIRED_FORMAT_VERSIONS[version]
            raise BrlInputError(f"model file {path} (format version {version}) was trained with "
                                f"{retired_message(knob, RETIRED_CONFIG[knob])}")
        if version != COMMAND_FORMAT_VERSION:
            raise BrlInputError(f"model file {path} has format version {version}, this brl reads "
                                f"{COMMAND_FORMAT_VERSION}")
        if names != list(BRANCH_NAMES):
            raise BrlInputError(f"model file {path} has branches {names}, expected {list(BRANCH_NAMES)}")
        branches = [BayesianAgent._from_npz(Prefixed(npz, f"{name}."), f"{path} (branch {name})") for name in names]
        if len({(b.state_dim, b.n_actions) for b in branches}) != 1:
            raise BrlInputError(f"model file {path} has branches of different state sizes or action counts")
        return cls.from_branches(branches)


COMMITTEE_KIND = "command-committee"
COMMITTEE_FORMAT_VERSION = 1
"""Version of a committee model file."""


class CommitteeAgent:
    """K command-conditioned agents trained apart (`brl train --task navigation --set committee=K`; outside the
    paper) that drive together: at each decision every member's branch of the command picks its greedy action and
    the committee takes the majority's (`majority_vote`). A trapped branch is a property of one run of learning,
    so the other members outvote it where it errs."""

    def __init__(self, members: list[CommandAgent]) -> None:
        if len(members) < 2:
            raise ValueError(f"a committee needs at least two members, got {len(members)}")
        if len({(m.state_dim, m.n_actions) for m in members}) != 1:
            raise ValueError("committee members must share the state size and the action count")
        self.members = list(members)

    @property
    def state_dim(self) -> int:
        """Length of the state vector."""
        return self.members[0].state_dim

    @property
    def n_actions(self) -> int:
        """Number of action primitives."""
        return self.members[0].n_actions

    @property
    def total_components(self) -> int:
        """Components of all members together."""
        return sum(m.total_components for m in self.members)

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator, greedy: bool = False) -> int:
        """The majority's greedy action under a command (a committee only acts greedily: its members train apart)."""
        if not greedy:
            raise ValueError("a committee acts greedily only; its members explore in their own training runs")
        return majority_vote(np.array([m.branch(command).action_probabilities(state) for m in self.members]))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Format version, kind, member count and each member's arrays under `member<k>.`."""
        arrays: dict[str, np.ndarray] = {"format_version": np.array(COMMITTEE_FORMAT_VERSION, dtype=np.int64),
                                         "kind": np.array(COMMITTEE_KIND), "members": np.array(len(self.members))}
        for k, member in enumerate(self.members):
            arrays.update({f"member{k}.{key}": v for key, v in member.to_arrays().items()})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write every member into one versioned .npz, atomically."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def _from_npz(cls, npz: Any, path: str) -> CommitteeAgent:
        """Validate the arrays of an open committee .npz and build the agent."""
        try:
            version, n = int(npz["format_version"]), int(npz["members"])
        except (KeyError, ValueError, TypeError) as exc:
            raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None
        if version != COMMITTEE_FORMAT_VERSION or n < 2:
            raise BrlInputError(f"model file {path} is a committee of format version {version} with {n} members; "
                                f"this brl reads version {COMMITTEE_FORMAT_VERSION} with at least two")
        members = [CommandAgent._from_npz(Prefixed(npz, f"member{k}."), f"{path} (member {k})") for k in range(n)]
        try:
            return cls(members)
        except ValueError as exc:
            raise BrlInputError(f"model file {path}: {exc}") from None


class RoadUserStop:
    """A navigation driver (command-conditioned agent or committee) whose stop primitive is taken only where the state
    shows a road user (`stop_rule` road_user; outside the paper), elsewhere its greedy choice among the other
    primitives: a standing car sees the same state, so a stop chosen with nothing in view would hold it for good."""

    def __init__(self, agent: CommandAgent | CommitteeAgent, stop: int) -> None:
        self.agent = agent
        self.stop = stop

    @property
    def state_dim(self) -> int:
        """Length of the state vector."""
        return self.agent.state_dim

    @property
    def n_actions(self) -> int:
        """Number of action primitives."""
        return self.agent.n_actions

    @property
    def total_components(self) -> int:
        """Components of the driver."""
        return self.agent.total_components

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator, greedy: bool = False) -> int:
        """The driver's greedy action, or with nothing in view its greedy choice without the stop primitive."""
        if not greedy:
            raise ValueError("the road-user stop rule acts greedily only")
        if road_user_in_view(state):
            return self.agent.act(state, command, rng, greedy=True)
        members = self.agent.members if isinstance(self.agent, CommitteeAgent) else [self.agent]
        probabilities = np.array([m.branch(command).action_probabilities(state) for m in members])
        probabilities[:, self.stop] = -1.0
        return majority_vote(probabilities)


def driver_from_npz(npz: Any, path: str) -> CommandAgent | CommitteeAgent:
    """A command-conditioned agent or a committee from an open .npz (or a prefixed view of one), by its kind."""
    kind = str(npz["kind"]) if "kind" in npz.files else ""
    if kind == COMMITTEE_KIND:
        return CommitteeAgent._from_npz(npz, path)
    return CommandAgent._from_npz(npz, path)


GATED_KIND = "brake-gated"
"""Kind of a brake-gated navigation model (`brlcli.agent.gate`)."""


def load_navigation_agent(path: str | os.PathLike[str]) -> Any:
    """A deployable navigation model: a command-conditioned agent, a committee of them or a brake-gated one, from its
    model file or from a member set's directory (`committee_members`; BrlInputError otherwise)."""
    members = committee_members(path)
    if members:
        agents = [CommandAgent.load(p) for p in members]
        try:
            return CommitteeAgent(agents) if len(agents) > 1 else agents[0]
        except ValueError as exc:
            raise BrlInputError(f"committee members in {path}: {exc}") from None
    path = model_file(path)
    npz = open_model_npz(path)
    with npz:
        if "kind" in npz.files and str(npz["kind"]) == GATED_KIND:
            from brlcli.agent.gate import BrakeGatedAgent

            return BrakeGatedAgent._from_npz(npz, path)
        return driver_from_npz(npz, path)


def is_command_model(path: str | os.PathLike[str]) -> bool:
    """Whether a model file (or a member set's first member) holds a command-conditioned agent, a committee or a
    brake-gated one (False for lane-keeping models, lane-keeping committees and unreadable files)."""
    path = (committee_members(path) or [model_file(path)])[0]
    try:
        with np.load(os.fspath(path), allow_pickle=False) as npz:
            return "kind" in npz.files and str(npz["kind"]) in (COMMAND_KIND, COMMITTEE_KIND, GATED_KIND)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, AttributeError, TypeError):
        return False
