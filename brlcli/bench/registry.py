"""The policy registry: every agent kind `brl bench` can run, built by name in any worker process.

It sits above the baselines it builds (each baseline's module is imported only when its kind is built) and below the
bench runner, which rebuilds every `PolicySpec` here in its workers. `find_models` turns `--model` / `--models` into
the BRL models of a bench; `baseline_specs` gives a baseline agent's policy options.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError
from brlcli.policy import AutopilotPolicy, BRLPolicy, OraclePolicy, Policy, PolicySpec

AGENTS = ("brl", "autopilot", "oracle", "mp", "il", "dqn")
"""The policy kinds. brl: Bayesian RL models; autopilot: privileged expert; oracle: the expert restricted to the BRL
agent's action primitives and decision rate; mp: modular pipeline; il: conditional imitation learning; dqn: deep RL
(Stable-Baselines3 DQN)."""

COMMANDLESS_SUITES = ("paper", "validation", "validation_starts")
"""Bench suites whose routes hold no junction, so no route command: a navigation model is not benched on them."""


def check_suite_task(suite: str, policy: Any) -> None:
    """A one-line error when a policy cannot be benched on a suite (a navigation model on a suite without commands)."""
    if getattr(policy, "task", "lane-keeping") == "navigation" and suite in COMMANDLESS_SUITES:
        raise BrlInputError(f"{policy.name} was trained for navigation (route commands); the {suite} suite is "
                            "lane keeping without commands: bench it on --suite corl2017, nocrash or nav_validation")


def build_policy(kind: str, name: str, options: dict[str, Any]) -> Policy:
    """A policy from its kind and options (a baseline's module is imported only when its kind is built)."""
    if kind == "brl":
        return BRLPolicy(name, **options)
    if kind == "autopilot":
        return AutopilotPolicy(name)
    if kind == "oracle":
        return OraclePolicy(name, **options)
    if kind == "mp":
        from brlcli.baselines.mp import ModularPipelinePolicy

        return ModularPipelinePolicy(name, **options)
    if kind == "il":
        from brlcli.baselines.il import ILPolicy

        return ILPolicy(name, **options)
    if kind == "dqn":
        from brlcli.baselines.deeprl import DeepRLPolicy

        return DeepRLPolicy(name, **options)
    raise BrlInputError(f"unknown agent '{kind}'; choose from {', '.join(AGENTS)}")


def baseline_specs(agent: str, model: str | None, deploy: str, segnet: str | None) -> list[tuple[str, dict]]:
    """(policy name, options) of a baseline agent: mp needs no model; il and dqn take --model or the shipped one."""
    if agent in ("autopilot", "oracle", "mp") and model is not None:
        raise BrlInputError(f"--agent {agent} has no trained model; drop --model")
    if agent in ("autopilot", "oracle"):
        return [(agent, {})]
    if agent == "mp":
        return [("mp", {"deploy": deploy, "segnet": segnet})]
    if agent in ("il", "dqn"):
        if model is None:
            return [(agent, {"model": None, "deploy": deploy, "segnet": segnet})]
        path = Path(model)
        name = f"{agent}/{path.parent.name if path.is_file() else path.name}"
        return [(name, {"model": str(path), "deploy": deploy, "segnet": segnet})]
    raise BrlInputError(f"unknown agent '{agent}'; choose from {', '.join(AGENTS)}")


def build_spec(spec: PolicySpec) -> Policy:
    """The policy a spec names (what a bench worker runs)."""
    return build_policy(spec.kind, spec.name, spec.options)


COMMITTEE_MEMBER_GLOBS = ("member_*/model.npz", "*/member_*/model.npz")
"""Where a committee run (or a shipped set of its members, models/brl_nav_empty) keeps its members' models."""


def _members_without_committee(where: str) -> str:
    """The error for a committee's members found where a committee model.npz was expected."""
    return (f"{where} holds committee members but no committee model.npz of its own: bench its seed directories "
            "as a set (--models DIR, or --model DIR/seed_N)")


def find_models(model: str | Sequence[str] | None, models: list[str] | None) -> list[tuple[str, str]]:
    """(policy name, model path) pairs from --model FILE (repeatable) or --models DIR|GLOB (a model set such as
    seed_0..8); a file given twice is listed once; models named alike (seed_0 of two sets) take their parent's name."""
    import glob as globmod

    from brlcli.agent.committee import committee_members

    found: list[tuple[str, str]] = []
    for one in [model] if isinstance(model, str) else list(model or []):
        p = Path(one)
        if committee_members(p):  # a member set: the policy assembles the committee
            found.append((p.resolve().name, str(p)))
        else:
            if p.is_dir():
                p = p / "model.npz"
            if not p.is_file():
                if any(p.parent.glob(COMMITTEE_MEMBER_GLOBS[1])):
                    raise BrlInputError(_members_without_committee(str(p.parent)))
                raise BrlInputError(f"model file {p} does not exist")
            found.append((p.parent.name or p.stem, str(p)))
    for item in models or []:
        hits = sorted(globmod.glob(item)) if any(ch in item for ch in "*?[") else [item]
        paths: list[Path] = []  # model files, or member sets' directories (a committee assembled in memory)
        for h in hits:
            hp = Path(h)
            if hp.is_file() or committee_members(hp):
                paths.append(hp)
            elif (hp / "model.npz").is_file():
                paths.append(hp / "model.npz")
            elif hp.is_dir():
                paths.extend(sorted([*hp.glob("*/model.npz"), *filter(committee_members, hp.iterdir())]))
        if not paths:
            if any(Path(h).is_dir() and any(Path(h).glob(g)) for h in hits for g in COMMITTEE_MEMBER_GLOBS):
                raise BrlInputError(_members_without_committee(f"--models '{item}'"))
            raise BrlInputError(f"--models '{item}' holds no model.npz files")
        for p in paths:
            run = p if p.is_dir() else p.parent
            found.append((f"{run.parent.name}/{run.name}", str(p)))
    if not found:
        from brlcli.models import default_model_set

        default = default_model_set()
        if default is None:
            raise BrlInputError("give a policy: --model FILE or --models DIR")
        return find_models(None, [str(default)])
    unique: dict[Path, tuple[str, str]] = {}
    for name, path in found:  # a model named twice (--model X and a --models set holding X) runs once
        unique.setdefault(Path(path).resolve(), (name, path))
    found = list(unique.values())
    names = [n for n, _ in found]
    if len(set(names)) != len(names):  # e.g. --model a/seed_0 --model b/seed_0: name them a/seed_0, b/seed_0
        found = [(_qualified(name, path) if names.count(name) > 1 else name, path) for name, path in found]
        names = [n for n, _ in found]
    if len(set(names)) != len(names):
        raise BrlInputError(f"two models are both named '{next(n for n in names if names.count(n) > 1)}'; give "
                            f"them distinct directories")
    return found


def _qualified(name: str, path: str) -> str:
    """A policy name with one more directory level: seed_0 -> set/seed_0."""
    run = Path(path) if Path(path).is_dir() else Path(path).parent
    return name if "/" in name else f"{run.resolve().parent.name}/{name}"
