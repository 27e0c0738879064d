"""`brl collect`: drive a town with the privileged autopilot and record frames to one ROS 2 bag per episode."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.autopilot import Autopilot, ExcursionConfig, NoiseConfig
from brlcli.bags import EpisodeBagWriter
from brlcli.errors import BrlInputError
from brlcli.outdir import refuse_existing
from brlcli.provenance import atomic_write_json, provenance
from brlcli.sim.camera import CameraConfig
from brlcli.sim.weather import get_weather
from brlcli.sim.world import World


@dataclass(frozen=True)
class CollectConfig:
    """What `brl collect` records (saved as `collect.json` beside the bags)."""

    town: str = "town01"
    weathers: tuple[int, ...] = (1, 3, 6, 8)
    episodes: int = 10
    episode_frames: int = 300
    every: int = 1
    seed: int = 0
    storage: str = "mcap"
    vehicles: int = 0
    pedestrians: int = 0
    noise: bool = True
    excursions: float = 0.0  # lateral excursions per second (sidewalks, opposite lane; outside CIL): 0 = none
    depth: bool = True
    camera: dict[str, Any] = field(default_factory=lambda: asdict(CameraConfig()))

    def __post_init__(self) -> None:
        if self.episodes < 1 or self.episode_frames < 1 or self.every < 1:
            raise BrlInputError("--episodes, --episode-frames and --every must be at least 1")
        if self.seed < 0:
            raise BrlInputError(f"--seed must be >= 0, got {self.seed}")
        if self.storage not in ("mcap", "sqlite3"):
            raise BrlInputError(f"--storage must be mcap or sqlite3, not '{self.storage}'")
        if not self.weathers:
            raise BrlInputError("--weathers needs at least one weather")
        if self.vehicles < 0 or self.pedestrians < 0:
            raise BrlInputError("traffic counts must be >= 0")
        if not 0.0 <= self.excursions <= 1.0:
            raise BrlInputError(f"--excursions is a rate per second between 0 and 1, not {self.excursions}")
        if self.excursions and self.vehicles:
            raise BrlInputError("--excursions drive into the opposite lane, where oncoming traffic blocks the car; "
                                "record excursions without --traffic")

    @classmethod
    def from_options(cls, town: str, weathers: str, episodes: int | None, frames: int | None, episode_frames: int,
                     every: int, seed: int, storage: str, traffic: bool, noise: bool, excursions: float, depth: bool,
                     width: int, height: int) -> CollectConfig:
        """The recording `brl collect`'s options describe: comma-separated weathers, --episodes or --frames (in
        whole episodes), CoRL2017's traffic with `traffic`, the camera's size; one-line errors."""
        from brlcli.sim.town import load_town
        from brlcli.sim.traffic import CORL_TRAFFIC

        name = load_town(town).name
        weather_ids = tuple(get_weather(w.strip()).id for w in weathers.split(",") if w.strip())
        if episodes is not None and frames is not None:
            raise BrlInputError("give --episodes or --frames, not both")
        if frames is not None:
            if frames < 1 or episode_frames < 1:
                raise BrlInputError("--frames and --episode-frames must be at least 1")
            episodes = math.ceil(frames / episode_frames)
        try:
            camera = asdict(CameraConfig(width=width, height=height))
        except ValueError as exc:
            raise BrlInputError(str(exc)) from None
        vehicles, pedestrians = CORL_TRAFFIC.get(name, (15, 50)) if traffic else (0, 0)
        return cls(town=town, weathers=weather_ids, episodes=10 if episodes is None else episodes,
                   episode_frames=episode_frames, every=every, seed=seed, storage=storage, vehicles=vehicles,
                   pedestrians=pedestrians, noise=noise, excursions=excursions, depth=depth, camera=camera)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        d = asdict(self)
        d["weathers"] = list(self.weathers)
        if not self.excursions:
            del d["excursions"]  # recordings without them keep their brl 0.1 configuration (and --resume)
        return d


def episode_name(k: int) -> str:
    """Directory name of episode `k`'s bag."""
    return f"episode_{k:05d}"


def check_output(cfg: CollectConfig, out: Path, resume: bool) -> None:
    """Refuse to mix recordings: an existing `out` needs `resume` and the same options."""
    cfg_path = Path(out) / "collect.json"
    if cfg_path.exists():
        refuse_existing(out, "a recording", resume, json.loads(cfg_path.read_text())["config"] == cfg.to_dict())


def collect(cfg: CollectConfig, out: Path, resume: bool = False,
            progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
    """Record `cfg.episodes` episodes to `out/episode_NNNNN/`; finished episodes are kept across interruptions."""
    out = Path(out)
    cfg_path = out / "collect.json"
    check_output(cfg, out, resume)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(cfg_path, provenance(cfg.to_dict(), kind="collect"))
    weathers = [get_weather(w) for w in cfg.weathers]
    world = World(cfg.town, weather=weathers[0], seed=cfg.seed, vehicles=cfg.vehicles, pedestrians=cfg.pedestrians,
                  camera=CameraConfig(**cfg.camera))
    town = world.town
    recorded, t0 = 0, time.perf_counter()
    try:
        for k in range(cfg.episodes):
            target = out / episode_name(k)
            if target.exists():
                continue  # finished in an earlier run
            rng = np.random.default_rng([cfg.seed, k])
            weather = weathers[k % len(weathers)]
            world.set_weather(weather)
            a, b = rng.choice(len(town.spawn_poses), size=2, replace=False)
            start = tuple(float(v) for v in town.spawn_poses[a])
            route = world.network.route(start, tuple(town.spawn_poses[b]))
            frame = world.reset(start, seed=int(rng.integers(2**31)))
            excursions = ExcursionConfig(rate_per_s=cfg.excursions) if cfg.excursions else None
            pilot = Autopilot(world, route, rng, NoiseConfig() if cfg.noise else None, excursions=excursions)
            meta = {"brl.town": town.name, "brl.town_version": town.version, "brl.weather": weather.id,
                    "brl.weather_name": weather.name, "brl.seed": cfg.seed, "brl.episode": k,
                    "brl.camera": cfg.camera, "brl.frame_dt_s": 0.1, "brl.route_length_m": round(route.length_m, 3)}
            writer = EpisodeBagWriter(target, meta, storage=cfg.storage, depth=cfg.depth)
            try:
                for i in range(cfg.episode_frames * cfg.every):
                    applied, expert = pilot.control(frame.measurements)
                    record = (i + 1) % cfg.every == 0
                    frame = world.step(applied, render=record)
                    if record:
                        s, _ = route.project(frame.measurements.x, frame.measurements.y)
                        writer.write(frame, expert, int(route.command_at(s)))
                        recorded += 1
                        if progress and recorded % 20 == 0:
                            progress(k, recorded, recorded / (time.perf_counter() - t0))
                    if pilot.done(frame.measurements):  # route finished: plan on to a new goal
                        nxt = tuple(town.spawn_poses[int(rng.integers(len(town.spawn_poses)))])
                        m = frame.measurements
                        route = world.network.route((m.x, m.y, m.yaw_deg), nxt)
                        pilot.route = route
                writer.close()
            except BaseException:
                writer.abort()
                raise
    finally:
        world.close()
    wall = time.perf_counter() - t0
    return {"frames": recorded, "wall_s": wall, "frames_per_s": recorded / wall if wall > 0 else math.nan,
            "bags": sorted(p.name for p in out.glob("episode_*"))}
