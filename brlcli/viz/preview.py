"""Pictures of a town for people: a top-down map with its routes and sample camera frames in several weathers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from brlcli.classes import colorize_labels
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.sim.roadnet import Route
from brlcli.sim.weather import get_weather
from brlcli.sim.world import World
from brlcli.viz.topdown import town_topdown


def check_previews(towns: list[str], weathers: str, seed: int) -> tuple[list[str], list[str]]:
    """`brl preview`'s towns and comma-separated weathers, checked before anything is drawn."""
    from brlcli.errors import BrlInputError
    from brlcli.sim.town import load_town

    for name in towns:
        load_town(name)
    weather_list = [w.strip() for w in weathers.split(",") if w.strip()]
    if not weather_list:
        raise BrlInputError(f"--weathers '{weathers}' names no weather; give ids or names, e.g. --weathers 1,6,8,14")
    for w in weather_list:
        get_weather(w)
    if seed < 0:
        raise BrlInputError(f"--seed must be >= 0, got {seed}")
    return list(towns), weather_list


def encode_png(rgb: np.ndarray) -> bytes:
    """RGB uint8 image -> PNG bytes."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _follow(world: World, route: Route, frames: int) -> None:
    """Drive along a route with a simple lane-centre controller (for picking camera views)."""
    from brlcli.sim.vehicle import Control

    for _ in range(frames):
        m = world.step(Control(), render=False).measurements
        s, lateral = route.project(m.x, m.y)
        ahead = min(s + 6.0, route.length_m)
        k = int(np.clip(np.searchsorted(route.cum_s, ahead), 1, len(route.points) - 1))
        d = route.points[k] - route.points[k - 1]
        err = (np.degrees(np.arctan2(d[1], d[0])) - m.yaw_deg + 180) % 360 - 180
        steer = float(np.clip(-0.04 * err + 0.25 * lateral, -1, 1))
        world.step(Control(steer=steer, throttle=0.45), render=False)


def make_preview(town: str, out_dir: Path, weathers: list[str], scale: int = 3, seed: int = 0) -> list[Path]:
    """Write `<town>_topdown.png` and `<town>_frames.png` (RGB beside labels per weather) into `out_dir`."""
    weather_list = [get_weather(w) for w in weathers]
    world = World(town, weather=weather_list[0], seed=seed, vehicles=8, pedestrians=20)
    written = []
    top = town_topdown(world.network, world.map, metres_per_px=0.4)
    path = out_dir / f"{world.town.name}_topdown.png"
    atomic_write_bytes(path, encode_png(top))
    written.append(path)
    rows = []
    for spec in (world.town.lane_keeping_routes[0], next(r for r in world.town.lane_keeping_routes
                                                          if r.kind != "straight")):
        route = world.network.route(spec.start, spec.goal)
        world.reset(spec.start, seed=seed)
        _follow(world, route, 25)
        for w in weather_list:
            world.set_weather(w)
            rgb, labels, _ = world.render()
            pair = np.concatenate([rgb, np.full((rgb.shape[0], 4, 3), 255, np.uint8), colorize_labels(labels)], 1)
            pair = cv2.resize(pair, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
            cv2.putText(pair, f"{w.id} {w.name}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1,
                        cv2.LINE_AA)
            rows.append(pair)
            rows.append(np.full((4, pair.shape[1], 3), 255, np.uint8))
    path = out_dir / f"{world.town.name}_frames.png"
    atomic_write_bytes(path, encode_png(np.concatenate(rows[:-1])))
    written.append(path)
    world.close()
    return written


def write_previews(towns: list[str], out_dir: Path, weathers: list[str], seed: int = 0) -> list[Path]:
    """Previews of several towns plus a `run.json` with the configuration, brl version and git commit."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for t in towns:
        written += make_preview(t, out_dir, weathers, seed=seed)
    config = {"command": "preview", "towns": towns, "weathers": weathers, "seed": seed}
    atomic_write_json(out_dir / "run.json", provenance(config, kind="preview"))
    return written
