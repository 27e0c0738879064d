"""`brl bench`: run a suite's episodes for one or more policies; one JSON line per finished episode.

Results directory:
    bench.json        suite, its version, town versions, policies, deploy input, seed, selection, brl version, commit
    results.jsonl     one line per finished episode, appended and flushed as it finishes (resume skips these)
    frames/<policy>/<episode id>.npz   per-frame measurements and controls of the episode (compressed)
Every episode's outcome depends only on its identifier, the policy and the bench seed, so results do not
depend on the number of workers, the shard or the order in which episodes ran.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.bench.metrics import FOOTPRINT_THRESHOLD, INFRACTION_RULES, episode_infractions, km_driven, paper_score
from brlcli.bench.registry import build_spec
from brlcli.bench.suites import GOAL_DISTANCE_M, SUITE_VERSION, build_suite
from brlcli.episode import EpisodeSpec
from brlcli.errors import BrlInputError
from brlcli.executor import Executor, run_tasks
from brlcli.npzio import npz_bytes
from brlcli.outdir import refuse_existing
from brlcli.policy import Observation, Policy, PolicySpec
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.sim.roadnet import Navigator
from brlcli.sim.town import load_town
from brlcli.sim.vehicle import Control
from brlcli.sim.world import FRAME_DT_S, World

REPLANNING_SUITES = ("corl2017", "nocrash", "nav_validation", "nav_validation_traffic")
"""Suites whose route commands are replanned when the car leaves its route (`Navigator`, as CARLA 0.8's planner in
CoRL2017 and NoCrash); the paper's lane-keeping suites keep the route planned at the start."""

LOG_FIELDS = ("game_time_s", "x", "y", "yaw_deg", "forward_speed_kmh", "collision_vehicles",
              "collision_pedestrians", "collision_other", "intersection_offroad", "intersection_otherlane")


def run_episode(world: World, spec: EpisodeSpec, policy: Policy, bench_seed: int) -> tuple[dict, dict]:
    """Drive one episode; returns the result record and the per-frame log arrays."""
    world.set_weather(spec.weather)
    navigator = Navigator(world.network, spec.start, spec.goal)
    replan = spec.suite in REPLANNING_SUITES
    frame = world.reset(spec.start, seed=spec.seed(bench_seed))
    policy.reset(spec, world)
    n_max = math.ceil(spec.timeout_s / FRAME_DT_S)
    log = {k: np.zeros(n_max + 1) for k in LOG_FIELDS}
    controls = np.zeros((n_max + 1, 3))
    for k in LOG_FIELDS:
        log[k][0] = getattr(frame.measurements, k)
    control, success, crashed, n = Control(), False, False, 0
    gx, gy = spec.goal[0], spec.goal[1]
    crash_rules = [INFRACTION_RULES[k] for k in ("collision_other", "collision_vehicles", "collision_pedestrians")] \
        if spec.end_on_collision else []
    for i in range(n_max):
        m = frame.measurements
        if i % policy.frames_per_decision == 0:
            if not getattr(policy, "needs_camera", True):
                rgb, labels, depth = None, None, None
            elif frame.labels is not None:
                rgb, labels, depth = frame.rgb, frame.labels, frame.depth
            else:
                rgb, labels, depth = world.render(rgb=getattr(policy, "needs_rgb", True))
            if replan:
                command = navigator.command(m.x, m.y, m.yaw_deg)
            else:
                command = navigator.route.command_at(navigator.route.project(m.x, m.y)[0])
            control = policy.decide(Observation(rgb, labels, m, int(command), depth))
        frame = world.step(control, render=False)
        n = i + 1
        for k in LOG_FIELDS:
            log[k][n] = getattr(frame.measurements, k)
        controls[n] = (control.steer, control.throttle, control.brake)
        if any(log[r.measurement][n] - log[r.measurement][max(n - r.skip, 0)] > r.threshold for r in crash_rules):
            crashed = True  # NoCrash: the collision ends the episode as a failure
            break
        if math.hypot(frame.measurements.x - gx, frame.measurements.y - gy) <= GOAL_DISTANCE_M:
            success = True
            break
    log = {k: v[: n + 1] for k, v in log.items()}
    log["control"] = controls[: n + 1]
    traffic = spec.vehicles + spec.pedestrians > 0
    infractions = episode_infractions(log, with_collisions=traffic)
    collisions = log["collision_vehicles"] + log["collision_pedestrians"] + log["collision_other"]
    off = log["intersection_offroad"][1:] > FOOTPRINT_THRESHOLD
    other = log["intersection_otherlane"][1:] > FOOTPRINT_THRESHOLD
    result = {
        **{k: getattr(spec, k) for k in ("suite", "condition", "task", "town", "weather", "index")},
        "id": spec.id, "policy": policy.name, "setting": policy.setting, "seed": spec.seed(bench_seed),
        "success": success, "time_s": round(n * FRAME_DT_S, 3), "timeout_s": spec.timeout_s,
        "route_length_m": spec.route_length_m, "km": km_driven(log["x"], log["y"]),
        "infractions": infractions, "collided": bool(collisions[-1] > 0),
        **({"crashed": crashed} if spec.end_on_collision else {}),
        "steps": int(n), "offroad_steps": int(off.sum()), "otherlane_steps": int(other.sum()),
        "either_steps": int((off | other).sum()),
        "final_distance_m": math.hypot(log["x"][-1] - gx, log["y"][-1] - gy),
        **({"replans": navigator.replans} if replan else {}),
    }
    return result, log


def world_for(cache: dict[tuple, World], spec: EpisodeSpec, policy: Policy) -> World:
    """The cached world for an episode's town and traffic, seen through the policy's camera (`policy.camera`, a
    CameraConfig, for state policies trained with another camera; default CoRL2017's)."""
    camera = getattr(policy, "camera", None)
    key = (spec.town, spec.vehicles, spec.pedestrians, camera)
    if key not in cache:
        cache[key] = World(spec.town, vehicles=spec.vehicles, pedestrians=spec.pedestrians, seed=0, camera=camera)
    return cache[key]


class _Worker:
    """Per-process cache: one world per (town, traffic) and one policy per policy spec."""

    def __init__(self, policies: list[PolicySpec], bench_seed: int) -> None:
        self.policy_specs = policies
        self.policies: dict[int, Policy] = {}
        self.worlds: dict[tuple, World] = {}
        self.seed = bench_seed

    def run(self, item: tuple[int, dict]) -> tuple[dict, bytes]:
        """One episode: its result record and its compressed frame log (written by the driver)."""
        p_idx, spec_dict = item
        spec = EpisodeSpec(**{**spec_dict, "start": tuple(spec_dict["start"]), "goal": tuple(spec_dict["goal"])})
        if p_idx not in self.policies:
            self.policies[p_idx] = build_spec(self.policy_specs[p_idx])
        policy = self.policies[p_idx]
        result, log = run_episode(world_for(self.worlds, spec, policy), spec, policy, self.seed)
        result["frames_file"] = f"frames/{safe_name(result['policy'])}/{safe_name(spec.id)}.npz"
        return result, npz_bytes(log, compress=True)

    def close(self) -> None:
        """Release the worlds' physics clients."""
        for world in self.worlds.values():
            world.close()
        self.worlds.clear()


def _bench_task(worker: _Worker, item: tuple[int, dict]) -> tuple[dict, bytes]:
    return worker.run(item)


def safe_name(text: str) -> str:
    """A policy name or episode id as a file name (what frames/ paths use)."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text)


def read_results(out: Path) -> list[dict]:
    """Finished episodes of a results directory (a torn last line from a crash is ignored)."""
    path = Path(out) / "results.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows


def prepare(out: Path, config: dict[str, Any], resume: bool) -> set[tuple[str, str]]:
    """Check or create a results directory; returns the (policy, episode id) pairs already finished."""
    out = Path(out)
    meta = out / "bench.json"
    if meta.exists():
        saved = json.loads(meta.read_text())["config"]
        refuse_existing(out, f"bench results ({saved.get('suite')})", resume, saved == config)
    elif resume and out.exists() and any(out.iterdir()):
        raise BrlInputError(f"{out} is not a bench results directory (no bench.json)")
    out.mkdir(parents=True, exist_ok=True)
    if not meta.exists():
        atomic_write_json(meta, provenance(config, kind="bench"))
    return {(r["policy"], r["id"]) for r in read_results(out)}


def run_bench(specs: list[EpisodeSpec], policies: list[PolicySpec], out: Path, config: dict[str, Any],
              workers: int = 1, resume: bool = False, progress: Callable[[dict], None] | None = None,
              executor: str | Executor = "local", ray_address: str | None = None) -> list[dict]:
    """Run every (policy, episode) not yet in `out` on the executor; returns all results of the directory.

    Workers return each episode's record and frame log; this process writes the frame file, then appends the
    record to results.jsonl (flushed), so the directory is the same whatever ran the episodes, and resumable.
    """
    ex = executor if isinstance(executor, Executor) else Executor(executor, workers, ray_address)
    ex.connect()  # a bad executor fails before anything is written
    try:
        done = prepare(out, config, resume)
        todo = [(i, s.as_dict()) for i, p in enumerate(policies) for s in specs if (p.name, s.id) not in done]
        setup = partial(_Worker, [p.with_absolute_paths() for p in policies], config["seed"])
        with open(Path(out) / "results.jsonl", "a", encoding="utf-8") as fh:
            for _, (result, frames) in run_tasks(_bench_task, todo, executor=ex, setup=setup):
                atomic_write_bytes(Path(out) / result["frames_file"], frames)
                fh.write(json.dumps(result, sort_keys=True) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
                if progress:
                    progress(result)
    finally:
        if ex is not executor:
            ex.close()
    return read_results(out)


def town_versions(specs: list[EpisodeSpec]) -> dict[str, str]:
    """Version of each town the episodes use (recorded so that reports refuse to mix town versions)."""
    return {t: load_town(t).version for t in sorted({s.town for s in specs})}


def suite_version(suite: str) -> int:
    """Version of a suite's definition."""
    return SUITE_VERSION[suite]


class SuiteEvaluator:
    """Runs a policy on a suite's episodes (worlds kept between calls); returns the paper's table figures."""

    def __init__(self, suite: str = "paper", bench_seed: int = 0, weathers: str | None = None) -> None:
        self.suite = suite
        self.specs: list[EpisodeSpec] = build_suite(suite, weathers=weathers)
        self.bench_seed = bench_seed
        self._worlds: dict[tuple, World] = {}

    def evaluate(self, policy: Any) -> dict[str, Any]:
        """Success, collision-free and Either shares and the Score over every episode of the suite."""
        results = []
        for spec in self.specs:
            results.append(run_episode(world_for(self._worlds, spec, policy), spec, policy, self.bench_seed)[0])
        n = len(results)
        steps = sum(r["steps"] for r in results)
        success = sum(r["success"] for r in results) / n
        collision_free = sum(not r["collided"] for r in results) / n
        either = sum(r["either_steps"] for r in results) / max(steps, 1)
        return {"episodes": n, "success": success, "collision_free": collision_free, "either": either,
                "score": paper_score(either, success, collision_free), "eval_suite": self.suite}

    def close(self) -> None:
        """Release the worlds' physics clients."""
        for w in self._worlds.values():
            w.close()
        self._worlds.clear()


def suite_evaluator(suite: str) -> SuiteEvaluator | None:
    """A learning curve's evaluator on `suite` (None for "none": no evaluation)."""
    return None if suite == "none" else SuiteEvaluator(suite)
