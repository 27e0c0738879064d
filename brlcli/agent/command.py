"""The command-conditioned Bayesian agent (issue 20; outside the paper): one Bayesian RL agent per route command.

In the spirit of conditional imitation learning's branches, the planner's high-level command (follow lane, left,
right, straight; `brlcli.sim.roadnet.BRANCH_COMMANDS`) selects one of four independent `BayesianAgent`s, each with
the paper's equations (and whatever `BRLParams` the run chose) and its own mixture model, action values and
schedules. The behaviour policy and the greedy action of a decision are those of the branch of the command at that
decision; the learning step (s_t, a_t, r_t, s_{t+1}) goes to the branch of the command at t, Algorithm 1 unchanged
inside it. Where the command changes between t and t+1, the TD target bootstraps (`bootstrap="next-branch"`, the
default) from the value of s_{t+1} in the branch of the command at t+1, the branch that acts there, as Q-learning on
the pair (state, command) would; `bootstrap="own-branch"` keeps the branch's own value of s_{t+1} (a branch then never
learns what its last decisions leave to the next one: a turn that ends in the wrong lane looks as good as one that
ends in the right one).

With `shared_mixture` (outside the paper, the issue's other design) the four commands share one mixture model: one
`BayesianAgent` whose components carry a block of action values per command (`n_blocks = 4`), each block with its own
alpha and tau; the branches are views of it (`BlockView`), so the junction commands act on the components that every
command's data builds, with action values of their own.

Model file: one `.npz` with `format_version`, `kind = "command-conditioned"`, `branches` (the branch names) and,
for each branch, the arrays of `BayesianAgent.save` under the prefix `<branch>.`; a shared-mixture model (format
version 3) has the shared agent's arrays under the prefix `shared.` instead.
"""

from __future__ import annotations

import os
import zipfile
from typing import Any

import numpy as np

from brlcli.agent.bayes import BayesianAgent, LearnStep, _one_line, open_model_npz, save_model_arrays
from brlcli.agent.params import BRLParams
from brlcli.errors import BrlInputError
from brlcli.sim.roadnet import BRANCH_NAMES, command_branch

COMMAND_FORMAT_VERSION = 1
"""Version of the command-conditioned model file."""
SHARED_STRAIGHT_FORMAT_VERSION = 2
"""Version of a file whose "go straight" command acts with the follow branch (`straight_as_follow`; brl before it
would read such a file as four branches and act with the empty straight one, so it refuses the version)."""
SHARED_MIXTURE_FORMAT_VERSION = 3
"""Version of a file whose commands share one mixture model (`shared_mixture`)."""
STRAIGHT = BRANCH_NAMES.index("straight")
COMMAND_KIND = "command-conditioned"
BOOTSTRAPS = ("next-branch", "own-branch")
"""Where a learning step whose next decision has another command takes the value of s_{t+1} from."""


class BlockView:
    """One command's block of action values in a shared-mixture agent, used as that command's branch: every
    attribute (act, learn, value, alpha, Q, ...) is the shared agent's with the block selected first."""

    def __init__(self, agent: BayesianAgent, block: int) -> None:
        self.agent = agent
        self.block = block

    def __getattr__(self, name: str) -> Any:
        agent = self.__dict__["agent"]
        agent.select_block(self.__dict__["block"])
        return getattr(agent, name)


class CommandAgent:
    """Four Bayesian RL agents, one per route command; `set_command` picks the branch `act` and `learn` use."""

    def __init__(self, state_dim: int = 30, n_actions: int = 4, params: BRLParams | None = None,
                 bootstrap: str = "next-branch", straight_as_follow: bool = False,
                 shared_mixture: bool = False) -> None:
        if shared_mixture:
            self._setup_shared(BayesianAgent(state_dim, n_actions, params, n_blocks=len(BRANCH_NAMES)), bootstrap)
        else:
            self._setup([BayesianAgent(state_dim, n_actions, params) for _ in BRANCH_NAMES], bootstrap,
                        straight_as_follow)

    def _setup(self, branches: list[Any], bootstrap: str, straight_as_follow: bool = False,
               shared: BayesianAgent | None = None) -> None:
        if bootstrap not in BOOTSTRAPS:
            raise ValueError(f"bootstrap must be one of {', '.join(BOOTSTRAPS)}, got {bootstrap!r}")
        self.branches = list(branches)
        self._branch = 0
        self.bootstrap = bootstrap
        self.straight_as_follow = bool(straight_as_follow)  # "go straight" acts and learns in the follow branch
        self.shared = shared  # the shared-mixture agent whose blocks the branches are (None: four agents)

    def _setup_shared(self, shared: BayesianAgent, bootstrap: str) -> None:
        if shared.n_blocks != len(BRANCH_NAMES):
            raise ValueError(f"a shared-mixture agent needs {len(BRANCH_NAMES)} blocks, got {shared.n_blocks}")
        self._setup([BlockView(shared, b) for b in range(len(BRANCH_NAMES))], bootstrap, shared=shared)

    def restart_branch(self, branch: int, warm: bool = False) -> None:
        """Restart one branch (its per-branch trap restart): a fresh agent, a `warm_copy` of the follow branch
        (`warm`), or, with a shared mixture, its block of action values forgotten (the components stay)."""
        if self.shared is not None:
            self.shared.reset_block(branch)
            return
        first = self.branches[0]
        self.branches[branch] = first.warm_copy() if warm else BayesianAgent(first.state_dim, first.n_actions,
                                                                               first.params)

    @classmethod
    def from_branches(cls, branches: list[BayesianAgent], bootstrap: str = "next-branch",
                      straight_as_follow: bool = False) -> CommandAgent:
        """An agent made of existing branches (in BRANCH_NAMES order)."""
        agent = cls.__new__(cls)
        agent._setup(branches, bootstrap, straight_as_follow)
        return agent

    def branch_of(self, command: int) -> int:
        """The branch (index into BRANCH_NAMES) that acts on a CARLA command code."""
        branch = int(command_branch(int(command)))
        return 0 if self.straight_as_follow and branch == STRAIGHT else branch

    def set_command(self, command: int) -> None:
        """Select the branch of a CARLA command code (2 follow, 3 left, 4 right, 5 straight; others follow)."""
        self._branch = self.branch_of(command)

    @property
    def branch(self) -> int:
        """Index of the branch in use (into BRANCH_NAMES)."""
        return self._branch

    @property
    def current(self) -> BayesianAgent:
        """The agent of the branch in use."""
        return self.branches[self._branch]

    @property
    def state_dim(self) -> int:
        """Length of the state vector."""
        return self.branches[0].state_dim

    @property
    def n_actions(self) -> int:
        """Number of action primitives."""
        return self.branches[0].n_actions

    @property
    def n_components(self) -> int:
        """Components of the branch in use."""
        return self.current.n_components

    @property
    def components_per_branch(self) -> list[int]:
        """Components of every branch, in BRANCH_NAMES order (with a shared mixture, the same for every branch)."""
        return [b.n_components for b in self.branches]

    @property
    def total_components(self) -> int:
        """Components of the whole agent (the shared mixture's, or the sum over the branches)."""
        return self.shared.n_components if self.shared is not None else sum(self.components_per_branch)

    @property
    def alpha(self) -> float:
        """Learning rate of the branch in use."""
        return self.current.alpha

    @property
    def tau(self) -> float:
        """Temperature of the branch in use."""
        return self.current.tau

    @property
    def rho(self) -> float:
        """Creation distance of the branch in use."""
        return self.current.rho

    def begin_episode(self, rng: np.random.Generator) -> None:
        """Start a training episode in every branch."""
        for b in self.branches:
            b.begin_episode(rng)

    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = False) -> int:
        """The branch's behaviour (or greedy) action for the state."""
        return self.current.act(state, rng, greedy=greedy)

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray,
              next_command: int | None = None) -> LearnStep:
        """One step of Algorithm 1 in the branch in use; with `next_command` naming another branch (and bootstrap
        next-branch) the target takes that branch's value of s_{t+1}."""
        nxt = None if next_command is None else self.branch_of(next_command)
        if nxt is None or nxt == self._branch or self.bootstrap == "own-branch":
            return self.current.learn(state, action, reward, next_state)
        value = self.branches[nxt].value(next_state)
        return self.current.learn(state, action, reward, next_state, next_value=value)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The model's arrays as `save` writes them: format version, kind, branch names, each branch's arrays."""
        version = SHARED_STRAIGHT_FORMAT_VERSION if self.straight_as_follow else COMMAND_FORMAT_VERSION
        if self.shared is not None:
            version = SHARED_MIXTURE_FORMAT_VERSION
        arrays: dict[str, np.ndarray] = {"format_version": np.array(version, dtype=np.int64),
                                         "kind": np.array(COMMAND_KIND), "branches": np.array(BRANCH_NAMES)}
        if self.shared is not None:
            arrays.update({f"shared.{k}": v for k, v in self.shared.to_arrays().items()})
            return arrays
        for name, b in zip(BRANCH_NAMES, self.branches, strict=True):
            arrays.update({f"{name}.{k}": v for k, v in b.to_arrays().items()})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write every branch into one versioned .npz, atomically."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def load(cls, path: str | os.PathLike[str], bootstrap: str = "next-branch") -> CommandAgent:
        """Read a model written by `save` (the bootstrap rule is a training choice, not stored); a lane-keeping model,
        a foreign or corrupt file raise BrlInputError."""
        path = os.fspath(path)
        npz = open_model_npz(path)
        with npz:
            return cls._from_npz(npz, path, bootstrap)

    @classmethod
    def _from_npz(cls, npz: Any, path: str, bootstrap: str) -> CommandAgent:
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
        known = (COMMAND_FORMAT_VERSION, SHARED_STRAIGHT_FORMAT_VERSION, SHARED_MIXTURE_FORMAT_VERSION)
        if version not in known:
            raise BrlInputError(f"model file {path} has format version {version}, this brl reads "
                                f"{', '.join(map(str, known))}")
        if names != list(BRANCH_NAMES):
            raise BrlInputError(f"model file {path} has branches {names}, expected {list(BRANCH_NAMES)}")
        if version == SHARED_MIXTURE_FORMAT_VERSION:
            shared = BayesianAgent._from_npz(_Prefixed(npz, "shared."), f"{path} (shared mixture)")
            if shared.n_blocks != len(BRANCH_NAMES):
                raise BrlInputError(f"model file {path} has a shared mixture with {shared.n_blocks} blocks of action "
                                    f"values, expected {len(BRANCH_NAMES)}")
            agent = cls.__new__(cls)
            agent._setup_shared(shared, bootstrap)
            return agent
        branches = []
        for name in names:
            branches.append(BayesianAgent._from_npz(_Prefixed(npz, f"{name}."), f"{path} (branch {name})"))
        if len({(b.state_dim, b.n_actions) for b in branches}) != 1:
            raise BrlInputError(f"model file {path} has branches of different state sizes or action counts")
        return cls.from_branches(branches, bootstrap, version == SHARED_STRAIGHT_FORMAT_VERSION)


TEAMS_KIND = "command-teams"
"""Kind of a training checkpoint of `TeamAgent` (never a deployable model)."""


class TeamAgent:
    """K command-conditioned agents ("teams") that learn from the same experience (outside the paper).

    In each training episode one team acts (team `episode % K`, `start_episode`); it learns from every step of its
    episode, and each other team from a random share of them (a bootstrap mask, as in Bootstrapped DQN; without it
    the teams, which start equal, would stay equal), with its own values (Algorithm 1 inside each branch, as
    `CommandAgent.learn`; off-policy for a team that did not act, as a Q-learning target is). A branch's trap is a
    property of one run of learning, so K teams are rarely all trapped in the same branch; `composed` builds the
    deployable agent from, for each command, the branch of the team whose own acting steps on that command earned
    the most reward in a recent window.
    """

    def __init__(self, teams: list[CommandAgent]) -> None:
        if len(teams) < 2:
            raise ValueError(f"a TeamAgent needs at least two teams, got {len(teams)}")
        self.teams = list(teams)
        self.acting = 0

    def start_episode(self, episode: int, rng: np.random.Generator) -> None:
        """Let team `episode % K` act in this episode (and draw its episode-level exploration)."""
        self.acting = episode % len(self.teams)
        self.teams[self.acting].begin_episode(rng)

    @property
    def current_team(self) -> CommandAgent:
        """The team acting in this episode."""
        return self.teams[self.acting]

    def set_command(self, command: int) -> None:
        """Select the branch of a CARLA command code in every team."""
        for team in self.teams:
            team.set_command(command)

    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = False) -> int:
        """The acting team's behaviour (or greedy) action."""
        return self.current_team.act(state, rng, greedy=greedy)

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray,
              next_command: int | None = None, mask: np.ndarray | None = None) -> LearnStep:
        """One learning step in the acting team and in every other team whose `mask` entry is true (all without a
        mask); returns the acting team's."""
        out = None
        for k, team in enumerate(self.teams):
            if k == self.acting or mask is None or mask[k]:
                step = team.learn(state, action, reward, next_state, next_command)
                out = step if k == self.acting else out
        assert out is not None
        return out

    @property
    def branch(self) -> int:
        """Index of the branch in use (into BRANCH_NAMES)."""
        return self.current_team.branch

    def __getattr__(self, name: str) -> Any:
        """Schedules and sizes (alpha, tau, rho, n_components, ...) are the acting team's."""
        if name in ("alpha", "tau", "rho", "n_components", "state_dim", "n_actions"):
            return getattr(self.teams[self.__dict__["acting"]], name)
        raise AttributeError(name)

    def composed(self, choice: list[int]) -> CommandAgent:
        """The deployable agent: for each branch (BRANCH_NAMES order), that branch of team `choice[branch]`."""
        first = self.teams[0]
        return CommandAgent.from_branches([self.teams[k].branches[b] for b, k in enumerate(choice)],
                                          first.bootstrap, first.straight_as_follow)

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write every team (a training checkpoint) into one versioned .npz, atomically."""
        arrays: dict[str, np.ndarray] = {"format_version": np.array(COMMAND_FORMAT_VERSION, dtype=np.int64),
                                         "kind": np.array(TEAMS_KIND), "teams": np.array(len(self.teams))}
        for k, team in enumerate(self.teams):
            arrays.update({f"team{k}.{key}": v for key, v in team.to_arrays().items()})
        save_model_arrays(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str], bootstrap: str = "next-branch") -> TeamAgent:
        """Read a checkpoint written by `save`; a foreign or corrupt file raises BrlInputError."""
        path = os.fspath(path)
        npz = open_model_npz(path)
        with npz:
            try:
                kind, n = str(npz["kind"]), int(npz["teams"])
            except (KeyError, ValueError, TypeError) as exc:
                raise BrlInputError(f"checkpoint {path} is not a team checkpoint: {_one_line(exc)}") from None
            if kind != TEAMS_KIND or n < 2:
                raise BrlInputError(f"checkpoint {path} is a '{kind}' file with {n} teams, not a team checkpoint")
            return cls([CommandAgent._from_npz(_Prefixed(npz, f"team{k}."), f"{path} (team {k})", bootstrap)
                        for k in range(n)])


COMMITTEE_KIND = "command-committee"
COMMITTEE_FORMAT_VERSION = 1
"""Version of a committee model file."""


def majority_vote(probabilities: np.ndarray) -> int:
    """The action most members choose greedily, given each member's p(a|s) as rows (K, |A|); a tie goes to the
    tied action with the highest mean p(a|s), then to the lowest index."""
    probabilities = np.asarray(probabilities, dtype=float)
    counts = np.bincount(probabilities.argmax(axis=1), minlength=probabilities.shape[1])
    return int(np.argmax(np.where(counts == counts.max(), probabilities.mean(axis=0), -np.inf)))


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

    def set_command(self, command: int) -> None:
        """Select the branch of a CARLA command code in every member."""
        for m in self.members:
            m.set_command(command)

    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = False) -> int:
        """The majority's greedy action (a committee only acts greedily: its members train apart)."""
        if not greedy:
            raise ValueError("a committee acts greedily only; its members explore in their own training runs")
        return majority_vote(np.array([m.current.action_probabilities(state) for m in self.members]))

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
        members = [CommandAgent._from_npz(_Prefixed(npz, f"member{k}."), f"{path} (member {k})", "next-branch")
                   for k in range(n)]
        try:
            return cls(members)
        except ValueError as exc:
            raise BrlInputError(f"model file {path}: {exc}") from None


def load_navigation_agent(path: str | os.PathLike[str]) -> CommandAgent | CommitteeAgent:
    """A deployable navigation model: a command-conditioned agent or a committee of them (BrlInputError otherwise)."""
    path = os.fspath(path)
    npz = open_model_npz(path)
    with npz:
        kind = str(npz["kind"]) if "kind" in npz.files else ""
        if kind == COMMITTEE_KIND:
            return CommitteeAgent._from_npz(npz, path)
        return CommandAgent._from_npz(npz, path, "next-branch")


class _Prefixed:
    """The entries of an open .npz under a key prefix, with the `files` / `[]` interface `_from_npz` reads."""

    def __init__(self, npz: Any, prefix: str) -> None:
        self._npz = npz
        self._prefix = prefix
        self.files = [k[len(prefix):] for k in npz.files if k.startswith(prefix)]

    def __getitem__(self, key: str) -> np.ndarray:
        return self._npz[self._prefix + key]


def is_command_model(path: str | os.PathLike[str]) -> bool:
    """Whether a model file holds a command-conditioned agent (False for lane-keeping models and unreadable files)."""
    try:
        with np.load(os.fspath(path), allow_pickle=False) as npz:
            return "kind" in npz.files
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, AttributeError, TypeError):
        return False
