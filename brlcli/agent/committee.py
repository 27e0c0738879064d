"""Committees of independently trained agents that drive by majority vote (outside the paper).

A run trapped in a wrong greedy action somewhere (a curve's entry, a branch at a junction) is a property of that run
of learning; agents trained apart rarely share it, so at each decision the committee takes the action most members
choose greedily (`majority_vote`) and the others outvote the one that errs. `LaneKeepingCommittee` holds paper agents
(`brl train --set committee=K`, the `action-averaging-committee` method); `brlcli.agent.command.CommitteeAgent` holds
command-conditioned ones for navigation. A committee acts greedily only: its members explore in their own runs.

Model file: `format_version`, `kind = "lane-keeping-committee"`, `members` and each member's arrays of
`BayesianAgent.save` under the prefix `member<k>.`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.agent.bayes import BayesianAgent, Prefixed, _one_line, open_model_npz, save_model_arrays
from brlcli.errors import BrlInputError

LANE_COMMITTEE_KIND = "lane-keeping-committee"
LANE_COMMITTEE_FORMAT_VERSION = 1
"""Version of a lane-keeping committee's model file."""


def majority_vote(probabilities: np.ndarray) -> int:
    """The action most members choose greedily, given each member's p(a|s) as rows (K, |A|); a tie goes to the
    tied action with the highest mean p(a|s), then to the lowest index."""
    probabilities = np.asarray(probabilities, dtype=float)
    counts = np.bincount(probabilities.argmax(axis=1), minlength=probabilities.shape[1])
    return int(np.argmax(np.where(counts == counts.max(), probabilities.mean(axis=0), -np.inf)))


class LaneKeepingCommittee:
    """K paper agents trained apart that drive by the majority of their greedy actions."""

    def __init__(self, members: list[BayesianAgent]) -> None:
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
        return sum(m.n_components for m in self.members)

    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = False) -> int:
        """The majority's greedy action (ties: the highest mean p(a|s), then the lowest index)."""
        if not greedy:
            raise ValueError("a committee acts greedily only; its members explore in their own training runs")
        return majority_vote(np.array([m.action_probabilities(state) for m in self.members]))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Format version, kind, member count and each member's arrays under `member<k>.`."""
        arrays: dict[str, np.ndarray] = {"format_version": np.array(LANE_COMMITTEE_FORMAT_VERSION, dtype=np.int64),
                                         "kind": np.array(LANE_COMMITTEE_KIND),
                                         "members": np.array(len(self.members))}
        for k, member in enumerate(self.members):
            arrays.update({f"member{k}.{key}": v for key, v in member.to_arrays().items()})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write every member into one versioned .npz, atomically."""
        save_model_arrays(path, self.to_arrays())

    @classmethod
    def _from_npz(cls, npz: Any, path: str) -> LaneKeepingCommittee:
        """Validate the arrays of an open committee .npz and build it."""
        try:
            version, n = int(npz["format_version"]), int(npz["members"])
        except (KeyError, ValueError, TypeError) as exc:
            raise BrlInputError(f"model file {path} is unreadable: {_one_line(exc)}") from None
        if version != LANE_COMMITTEE_FORMAT_VERSION or n < 2:
            raise BrlInputError(f"model file {path} is a lane-keeping committee of format version {version} with {n} "
                                f"members; this brl reads version {LANE_COMMITTEE_FORMAT_VERSION} with at least two")
        members = [BayesianAgent._from_npz(Prefixed(npz, f"member{k}."), f"{path} (member {k})") for k in range(n)]
        try:
            return cls(members)
        except ValueError as exc:
            raise BrlInputError(f"model file {path}: {exc}") from None


def committee_members(path: str | os.PathLike[str]) -> list[Path]:
    """The members' model files of a committee run directory without a model.npz of its own (a shipped member set
    such as models/brl_nav_empty/seed_0), in member order; [] for anything else."""
    run = Path(path)
    if not run.is_dir() or (run / "model.npz").exists():
        return []
    members = [p for p in run.glob("member_*/model.npz") if p.parent.name.removeprefix("member_").isdigit()]
    return sorted(members, key=lambda p: int(p.parent.name.removeprefix("member_")))


def model_file(path: str | os.PathLike[str]) -> str:
    """The model file a path names: a run directory's own model.npz where it has one, else the path itself."""
    run = Path(path)
    return os.fspath(run / "model.npz") if run.is_dir() and (run / "model.npz").is_file() else os.fspath(path)


def load_lane_keeping_agent(path: str | os.PathLike[str]) -> BayesianAgent | LaneKeepingCommittee:
    """A deployable lane-keeping model: the paper's agent or a committee of them, from its model file or from a
    member set's directory (`committee_members`; BrlInputError otherwise)."""
    members = committee_members(path)
    if members:
        agents = [BayesianAgent.load(p) for p in members]
        try:
            return LaneKeepingCommittee(agents) if len(agents) > 1 else agents[0]
        except ValueError as exc:
            raise BrlInputError(f"committee members in {path}: {exc}") from None
    path = model_file(path)
    npz = open_model_npz(path)
    with npz:
        kind = str(npz["kind"]) if "kind" in npz.files else ""
        if kind == LANE_COMMITTEE_KIND:
            return LaneKeepingCommittee._from_npz(npz, path)
        if kind:
            raise BrlInputError(f"model file {path} is a '{kind}' model, not a lane-keeping one")
    return BayesianAgent.load(path)
