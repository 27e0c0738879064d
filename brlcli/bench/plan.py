"""What a `brl bench` run is: its episodes, its policies (every model loaded once, so a bad file fails before anything
is written) and the configuration record saved as bench.json; `summary_rows` gives the end-of-run table."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from brlcli.bench.metrics import model_stats
from brlcli.bench.registry import baseline_specs, build_spec, check_suite_task, find_models
from brlcli.bench.runner import suite_version, town_versions
from brlcli.bench.suites import build_suite, parse_shard, shard, subset
from brlcli.episode import EpisodeSpec
from brlcli.errors import BrlInputError
from brlcli.policy import PolicySpec, model_variant
from brlcli.segnet import check_input_source


@dataclass(frozen=True)
class BenchPlan:
    """A bench's episodes, policies and bench.json configuration."""

    specs: list[EpisodeSpec]
    policies: list[PolicySpec]
    config: dict[str, Any]

    @property
    def total(self) -> int:
        """Episodes the bench runs (every policy on every episode)."""
        return len(self.specs) * len(self.policies)


def bench_record(suite: str, specs: list[EpisodeSpec], policies: list[PolicySpec], deploy: str, seed: int,
                 selection: dict[str, Any], shard_kn: tuple[int, int] = (1, 1),
                 variants: dict[str, str] | None = None) -> dict[str, Any]:
    """The bench.json configuration of a run: suite and its version, town versions, policies (BRL models with their
    method variant: `variants` by policy name, else read beside each model), deployment input, bench seed, the
    episode selection and the shard."""
    variants = variants or {p.name: model_variant(Path(p.options["model"])) for p in policies if p.kind == "brl"}
    return {"suite": suite, "suite_version": suite_version(suite), "town_versions": town_versions(specs),
            "policies": [{"kind": p.kind, "name": p.name, **p.options,
                          **({"variant": variants[p.name]} if p.name in variants else {})} for p in policies],
            "deploy": deploy, "seed": seed, "selection": selection, "shard": list(shard_kn)}


def plan_bench(suite: str, agent: str = "brl", model: str | Sequence[str] | None = None,
               models: list[str] | None = None,
               deploy: str = "gt", segnet: str | None = None, conditions: str | None = None,
               tasks: str | None = None, weathers: str | None = None, episodes: str | None = None,
               shard_text: str | None = None, seed: int = 0) -> BenchPlan:
    """Validate `brl bench`'s options into a plan; nothing is written."""
    if seed < 0:
        raise BrlInputError(f"--seed must be >= 0, got {seed}")
    k, n = parse_shard(shard_text)
    specs = shard(subset(build_suite(suite, conditions, tasks, weathers), episodes), k, n)
    if deploy not in ("gt", "estimated"):
        raise BrlInputError(f"--deploy must be gt or estimated, not '{deploy}'")
    check_input_source(deploy)
    if agent == "brl":
        policies = [PolicySpec("brl", name, {"model": path, "deploy": deploy, "segnet": segnet})
                    for name, path in find_models(model, models)]
    else:
        given = [model] if isinstance(model, str) else list(model or [])
        if models or len(given) > 1:
            raise BrlInputError(f"--models and a repeated --model are for brl models; give --agent {agent} one "
                                f"--model (one bench per baseline model, then brl report merges them)")
        policies = [PolicySpec(agent, name, opts)
                    for name, opts in baseline_specs(agent, given[0] if given else None, deploy, segnet)]
    for p in policies:  # load every model once here: a bad file fails before anything is written
        check_suite_task(suite, build_spec(p))
    selection = {"conditions": conditions, "tasks": tasks, "weathers": weathers, "episodes": episodes}
    return BenchPlan(specs, policies, bench_record(suite, specs, policies, deploy, seed, selection, (k, n)))


def summary_rows(plan: BenchPlan, results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per policy with results: setting, episodes, success, collision-free and Either shares, km."""
    rows = []
    for p in plan.policies:
        episodes = [r for r in results if r["policy"] == p.name]
        if episodes:
            stats = model_stats(episodes[0]["setting"], p.name, episodes)
            rows.append({"policy": p.name, "setting": stats.setting, "episodes": stats.episodes,
                         "success": stats.success, "collision_free": stats.no_collision, "either": stats.either,
                         "km": stats.dist_m / 1000.0})
    return rows
