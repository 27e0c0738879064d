"""Deep RL baseline: Stable-Baselines3 DQN on the BRL agent's task (same env, 30-number state, reward, actions).

The action set, training traffic and hazard reward are brl train's options of the same names (`actions`, `traffic`,
`r_hazard`, `hazard_predict_s`; outside the paper, issue 35), so a DQN can be trained with the brake on the reward a
braking BRL agent learns from.

Training runs in chunks of `eval_every` environment steps. Each chunk starts from a fresh environment reset and
seeds every generator (python, numpy, torch, action space, env) from (seed, chunk), so a run resumed from the
checkpoint of its last finished chunk is bit-identical to an uninterrupted one. After each chunk the greedy
Q-network is evaluated on the evaluation suite and a row is added to `learning_curve.csv` (see brlcli.curve).

Run directory:
    config.json          resolved configuration + brl version + git commit
    learning_curve.csv   paper-suite success etc. after every chunk (env steps = decisions)
    drl.pt               the Q-network of the last finished chunk (torch, weights_only, format-versioned)
    checkpoint/          Q and target networks, optimizer, replay buffer (npz), counters: the resume point
    summary.json         at the end: steps, wall and evaluation time, learning steps/s, final evaluation
SB3's own save/load (which unpickles) is never used: networks are written as plain state dicts.
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from brlcli.config import Layer, check_known_keys, resolve
from brlcli.curve import CURVE_FILE, Evaluator, write_curve
from brlcli.devices import check_device_name, resolve_device
from brlcli.errors import BrlInputError
from brlcli.features import STATE_DIM
from brlcli.outdir import refuse_existing
from brlcli.policy import StatePolicy, setting_name
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.retired import unknown_action_set
from brlcli.reward import HazardRewardParams, RewardParams, RouteRewardParams
from brlcli.segnet import check_input_source, labeler_for
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import ACTION_SETS, DrivingEnv, action_set_traits
from brlcli.sim.navroutes import TASK_ROUTE_KINDS, TASKS
from brlcli.sim.roadnet import BRANCH_NAMES, command_branch
from brlcli.torchfiles import load_torch_doc, save_torch_doc

DRL_FORMAT = "brl-drl"
DRL_FORMAT_VERSION = 1
CHECKPOINT_VERSION = 1
ALGOS = ("dqn",)


@dataclass(frozen=True)
class DeepRLConfig:
    """A deep RL training run (saved as `config.json`); defaults are the documented budget."""

    algo: str = "dqn"
    task: str = "lane-keeping"  # or "navigation": brl train's task (the route command enters the state one-hot)
    town: str = "town01"
    weather: int = 1
    input: str = "gt"
    steps: int = 100_000
    eval_every: int = 5_000
    eval_suite: str = "auto"  # paper, nav_validation or none; auto: the task's (paper for lane keeping)
    seed: int = 0
    learning_rate: float = 5e-4
    buffer_size: int = 100_000
    learning_starts: int = 1_000
    batch_size: int = 64
    gamma: float = 0.9
    train_freq: int = 4
    target_update_interval: int = 1_000
    exploration_fraction: float = 0.3
    exploration_final_eps: float = 0.05
    net_arch: tuple[int, ...] = (64, 64)
    target_speed_kmh: float = 20.0
    segnet: str | None = None
    road_view: str = "road+line"  # the road-view reward's share, as `brl train`'s default (docs/lane-keeping-study.md)
    offroad_end: float | None = 0.5  # a training episode ends beyond this off-road share, as `brl train`'s default
    otherlane_end: float | None = None  # ... and beyond this share in the opposite lane (brl train's option)
    start_offset_m: float = 0.0  # training episodes start with a lateral offset ~ U(-a, a) m (brl train's option)
    start_yaw_deg: float = 0.0  # ... and a heading offset ~ U(-b, b) degrees
    camera_pitch_deg: float = -15.0  # pitch of the state camera (deg), as brl train's
    actions: str = "paper"  # brl train's action set: paper (the four primitives), stop, fine or fine_stop
    traffic: tuple[str, ...] = ()  # outside the paper: NoCrash traffic levels of the training episodes (brl train's)
    r_hazard: float = 0.0  # outside the paper, > 0: brl train's hazard reward (HazardRewardParams)
    hazard_predict_s: float = 0.0  # ... predicting road users this far ahead (s)
    device: str = "cpu"  # SB3's device for the networks: cpu (the default), cuda, cuda:N or auto (brlcli.devices)

    def __post_init__(self) -> None:
        check_device_name(self.device, "--device")
        if self.algo not in ALGOS:
            raise BrlInputError(f"unknown deep RL algorithm '{self.algo}'; choose from {', '.join(ALGOS)}")
        check_input_source(self.input, "--input")
        if self.steps < 1 or self.eval_every < 1:
            raise BrlInputError("--steps and --eval-every must be at least 1")
        if self.seed < 0:
            raise BrlInputError(f"--seed must be >= 0, got {self.seed}")
        if self.eval_every % self.train_freq:
            raise BrlInputError(f"--eval-every must be a multiple of the train frequency ({self.train_freq})")
        if self.task not in TASKS:
            raise BrlInputError(f"unknown task '{self.task}'; choose one of {', '.join(TASKS)}")
        if self.eval_suite not in ("auto", "paper", "nav_validation", "nav_validation_traffic", "none"):
            raise BrlInputError("--eval-suite must be paper, nav_validation, nav_validation_traffic or none, not "
                                f"'{self.eval_suite}'")
        if (self.eval_suite.startswith("nav_validation") and self.task != "navigation") or \
                (self.task, self.eval_suite) == ("navigation", "paper"):
            raise BrlInputError(f"--eval-suite {self.eval_suite} does not fit --task {self.task}: lane keeping "
                                "evaluates on paper, navigation on nav_validation (its routes need commands)")
        if self.r_hazard and not self.traffic:
            raise BrlInputError("the hazard reward (r_hazard) needs traffic levels, e.g. --set "
                                "'traffic=[\"empty\",\"regular\",\"dense\"]'")
        from brlcli.sim.weather import get_weather

        get_weather(self.weather)
        try:
            self.reward_params()
            self.hazard_reward()
            DrivingEnv.check_traffic_options(self.actions, self.traffic, "paper", 0.0)
            DrivingEnv.check_episode_rules(self.offroad_end, self.start_offset_m, self.start_yaw_deg,
                                           self.otherlane_end)
            self.camera()
        except ValueError as exc:
            raise BrlInputError(f"bad deep RL configuration: {exc}") from None

    def reward_params(self) -> RewardParams:
        """The reward's parameters for this run (as `brl train`'s)."""
        return RewardParams(target_speed_kmh=self.target_speed_kmh, road_view=self.road_view)

    def hazard_reward(self) -> HazardRewardParams | None:
        """The hazard reward terms (None when r_hazard is 0: the paper's reward), as brl train's."""
        if not self.r_hazard:
            return None
        return HazardRewardParams(r_hazard=self.r_hazard, predict_s=self.hazard_predict_s)

    def camera(self) -> CameraConfig:
        """The state camera of this run (CoRL2017's mount and size, the configured pitch)."""
        return CameraConfig(pitch_deg=self.camera_pitch_deg)

    @property
    def evaluation_suite(self) -> str:
        """The learning curve's suite: `eval_suite`, with auto resolved to the task's (paper or nav_validation;
        nav_validation_traffic for navigation trained in traffic, as brl train's)."""
        if self.eval_suite == "auto":
            if self.task == "navigation":
                return "nav_validation_traffic" if self.traffic else "nav_validation"
            return "paper"
        return self.eval_suite

    @property
    def state_dim(self) -> int:
        """Length of the network's input: the 30-number state, plus the one-hot command for navigation."""
        return STATE_DIM + (len(BRANCH_NAMES) if self.task == "navigation" else 0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        d = asdict(self)
        d["net_arch"] = list(self.net_arch)
        d["traffic"] = list(self.traffic)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DeepRLConfig:
        """Inverse of `to_dict`; unknown keys are an error."""
        check_known_keys(cls, d, "deep RL")
        d = dict(d)
        if "road_view" not in d:  # written before brl train's study defaults: brl 0.1's reward and episodes
            d.update(road_view="road", offroad_end=None)
        for key in ("net_arch", "traffic"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)


def resolve_deep_rl_config(layers: Sequence[Layer]) -> DeepRLConfig:
    """The deep RL configuration of a command line's layers (`brlcli.config.command_layers`), validated once; estimated
    input without a net gets the shipped one (recorded in the config)."""
    from brlcli.sim.town import load_town

    cfg = resolve(DeepRLConfig, layers, "deep RL")
    cfg = replace(cfg, device=resolve_device(cfg.device))  # recorded as the device it runs on
    if cfg.segnet is not None and cfg.input != "estimated":
        raise BrlInputError("--segnet is only used with --input estimated")
    if cfg.input == "estimated" and cfg.segnet is None:
        from brlcli.models import default_segnet_path

        cfg = replace(cfg, segnet=str(default_segnet_path()))
    load_town(cfg.town)
    return cfg


def q_network(net_arch: tuple[int, ...], state_dim: int, n_actions: int) -> nn.Sequential:
    """The MLP Q-network with SB3's layer layout (Linear, ReLU, ..., Linear), so state dicts match."""
    layers: list[nn.Module] = []
    width = state_dim
    for h in net_arch:
        layers += [nn.Linear(width, h), nn.ReLU()]
        width = h
    layers.append(nn.Linear(width, n_actions))
    return nn.Sequential(*layers)


def save_model(path: Path, q_net: nn.Module, cfg: DeepRLConfig, env_steps: int) -> None:
    """Write a Q-network file (state dict, architecture, training config) atomically."""
    save_torch_doc(path, DRL_FORMAT, DRL_FORMAT_VERSION, {
        "algo": cfg.algo, "net_arch": list(cfg.net_arch), "state_dim": cfg.state_dim,
        "n_actions": len(ACTION_SETS[cfg.actions]),
        "env_steps": env_steps, "train": json.dumps(cfg.to_dict(), sort_keys=True),
        "state_dict": {k: v.cpu() for k, v in q_net.state_dict().items()}})


def load_model(path: str | Path) -> tuple[nn.Sequential, dict[str, Any]]:
    """A Q-network file -> (network in eval mode, metadata with the training config); never unpickles."""
    path = Path(path)
    if path.is_dir():
        path = path / "drl.pt"
    doc = load_torch_doc(path, DRL_FORMAT, DRL_FORMAT_VERSION, "deep RL model", "brl train-rl")
    try:
        state_dim, n_actions = int(doc["state_dim"]), int(doc["n_actions"])
        train = json.loads(doc["train"])
        actions = str(train.get("actions", "paper"))
        if actions not in ACTION_SETS:
            raise BrlInputError(f"deep RL model {path}: {unknown_action_set(actions, ACTION_SETS)}")
        if state_dim not in (STATE_DIM, STATE_DIM + len(BRANCH_NAMES)) or n_actions != len(ACTION_SETS[actions]):
            raise BrlInputError(f"deep RL model {path} has state size {state_dim} and {n_actions} actions; brl's "
                                f"task uses {STATE_DIM} (+{len(BRANCH_NAMES)} for navigation) and action set "
                                f"'{actions}' {len(ACTION_SETS[actions])}")
        net = q_network(tuple(int(h) for h in doc["net_arch"]), state_dim, n_actions)
        net.load_state_dict(doc["state_dict"])
        meta = {"algo": str(doc["algo"]), "env_steps": int(doc["env_steps"]), "train": train}
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise BrlInputError(f"deep RL model {path} is damaged: {exc}".splitlines()[0]) from None
    return net.eval(), meta


def greedy_action_fn(net: nn.Module) -> Callable[[np.ndarray], int]:
    """state (30,) -> argmax_a Q(state, a)."""

    def act(state: np.ndarray) -> int:
        with torch.inference_mode():
            q = net(torch.as_tensor(np.asarray(state, dtype=np.float32))[None])
        return int(q[0].argmax())

    return act


def with_command(state: np.ndarray, command: int) -> np.ndarray:
    """The navigation network's input: the 30-number state and the one-hot branch of the route command."""
    onehot = np.zeros(len(BRANCH_NAMES), np.float32)
    onehot[int(command_branch(int(command)))] = 1.0
    return np.concatenate([np.asarray(state, np.float32), onehot])


def greedy_command_action_fn(net: nn.Module) -> Callable[[np.ndarray, int], int]:
    """(state, command) -> argmax_a Q([state, one-hot command], a)."""
    act = greedy_action_fn(net)
    return lambda state, command: act(with_command(state, command))


class CommandObservation(gym.Wrapper):
    """Appends the one-hot route command of the next decision (info['command']) to the driving env's state."""

    def __init__(self, env: DrivingEnv) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(STATE_DIM + len(BRANCH_NAMES),), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        """Reset the env; the observation carries the first command."""
        obs, info = self.env.reset(**kwargs)
        return with_command(obs, info["command"]), info

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Step the env; the observation carries the next command."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        return with_command(obs, info["command"]), reward, terminated, truncated, info


class DeepRLPolicy(StatePolicy):
    """A trained DQN deployed greedily on GT or estimated labels (decision every 7 frames), for `brl bench`."""

    def __init__(self, name: str = "dqn", model: str | None = None, deploy: str = "gt",
                 segnet: str | None = None) -> None:
        check_input_source(deploy)
        if model is None:
            from brlcli.models import models_dir

            model = str(models_dir() / "dqn" / "drl.pt")
        net, meta = load_model(model)
        self.task = str(meta["train"].get("task", "lane-keeping"))
        setting = f"{meta['algo'].upper()}-{setting_name(meta['train'].get('input', 'gt'), deploy)}"
        pitch = float(meta["train"].get("camera_pitch_deg", CameraConfig().pitch_deg))
        nav = self.task == "navigation"
        actions = str(meta["train"].get("actions", "paper"))
        label = ", ".join(["navigation"] * nav + action_set_traits(actions))
        super().__init__(name, f"{setting} ({label})" if label else setting,
                         greedy_command_action_fn(net) if nav else greedy_action_fn(net),
                         labeler_for(deploy, segnet), CameraConfig(pitch_deg=pitch), uses_command=nav,
                         actions=actions)


@dataclass
class DeepRLProgress:
    """A progress report of a deep RL run."""

    env_steps: int
    steps: int
    episodes: int
    exploration: float
    success: float | None = None
    done: bool = False


def _chunk_seed(seed: int, chunk: int) -> int:
    return int(np.random.default_rng([seed, chunk, 11]).integers(2**31))


def _make_env(cfg: DeepRLConfig) -> Any:
    nav = cfg.task == "navigation"
    env = DrivingEnv(town=cfg.town, weather=cfg.weather, routes="navigation" if nav else "training",
                     kinds=TASK_ROUTE_KINDS[cfg.task], reward=cfg.reward_params(),
                     labeler=labeler_for(cfg.input, cfg.segnet, "--input"), camera=cfg.camera(),
                     offroad_end=cfg.offroad_end, start_offset_m=cfg.start_offset_m,
                     start_yaw_deg=cfg.start_yaw_deg, otherlane_end=cfg.otherlane_end,
                     route_reward=RouteRewardParams() if nav else None, actions=cfg.actions,
                     traffic=tuple(cfg.traffic), hazard=cfg.hazard_reward())
    return CommandObservation(env) if nav else env


def _build_dqn(cfg: DeepRLConfig, env: Any) -> Any:
    from stable_baselines3 import DQN
    from stable_baselines3.common.logger import Logger

    model = DQN("MlpPolicy", env, learning_rate=cfg.learning_rate, buffer_size=cfg.buffer_size,
                learning_starts=cfg.learning_starts, batch_size=cfg.batch_size, gamma=cfg.gamma,
                train_freq=cfg.train_freq, target_update_interval=cfg.target_update_interval,
                exploration_fraction=cfg.exploration_fraction, exploration_final_eps=cfg.exploration_final_eps,
                policy_kwargs={"net_arch": list(cfg.net_arch)}, seed=cfg.seed, device=cfg.device, verbose=0)
    # SB3's default logger makes an empty /tmp/SB3-<date> directory on every learn(); brl logs its own curve
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def _save_checkpoint(run_dir: Path, model: Any, chunk: int, curve: list[dict], wall_s: float,
                     eval_s: float) -> None:
    """Networks and replay buffer under chunk-numbered names, then state.json (the commit point) naming them;
    files of older chunks are removed last, so a kill at any moment leaves a consistent checkpoint."""
    from brlcli.npzio import save_npz

    ckpt = run_dir / "checkpoint"
    nets, replay = f"networks_{chunk:05d}.pt", f"replay_{chunk:05d}.npz"
    buf = io.BytesIO()
    torch.save({"q_net": model.q_net.state_dict(), "q_net_target": model.q_net_target.state_dict(),
                "optimizer": model.policy.optimizer.state_dict()}, buf)
    atomic_write_bytes(ckpt / nets, buf.getvalue())
    rb = model.replay_buffer
    save_npz(ckpt / replay, {k: getattr(rb, k) for k in _BUFFER_ARRAYS}, compress=True)
    atomic_write_json(ckpt / "state.json", {
        "version": CHECKPOINT_VERSION, "chunk": chunk, "networks": nets, "replay": replay,
        "num_timesteps": int(model.num_timesteps), "n_calls": int(model._n_calls), "n_updates": int(model._n_updates),
        "episode_num": int(model._episode_num), "buffer_pos": int(rb.pos), "buffer_full": bool(rb.full),
        "curve": curve, "wall_s": wall_s, "eval_s": eval_s})
    for old in ckpt.iterdir():
        if old.name not in (nets, replay, "state.json") and old.suffix in (".pt", ".npz"):
            old.unlink(missing_ok=True)


def _load_checkpoint(run_dir: Path, model: Any) -> dict[str, Any] | None:
    ckpt = run_dir / "checkpoint"
    if not (ckpt / "state.json").exists():
        return None
    try:
        state = json.loads((ckpt / "state.json").read_text())
        if state.get("version") != CHECKPOINT_VERSION:
            raise BrlInputError(f"checkpoint {ckpt} has version {state.get('version')}, this brl reads "
                                f"{CHECKPOINT_VERSION}")
        nets = torch.load(ckpt / state["networks"], map_location="cpu", weights_only=True)
        model.q_net.load_state_dict(nets["q_net"])
        model.q_net_target.load_state_dict(nets["q_net_target"])
        model.policy.optimizer.load_state_dict(nets["optimizer"])
        with np.load(ckpt / state["replay"], allow_pickle=False) as z:
            for k in _BUFFER_ARRAYS:
                getattr(model.replay_buffer, k)[...] = z[k]
    except BrlInputError:
        raise
    except Exception as exc:
        raise BrlInputError(f"checkpoint {ckpt} is damaged ({type(exc).__name__}); delete the run directory to start "
                            "over") from None
    model.num_timesteps = state["num_timesteps"]
    model._n_calls = state["n_calls"]
    model._n_updates = state["n_updates"]
    model._episode_num = state["episode_num"]
    model.replay_buffer.pos = state["buffer_pos"]
    model.replay_buffer.full = state["buffer_full"]
    return state


def check_run_dir(cfg: DeepRLConfig, run_dir: Path, resume: bool) -> None:
    """Refuse to overwrite a run, or to resume one made with other options."""
    config_path = Path(run_dir) / "config.json"
    if config_path.exists():
        refuse_existing(run_dir, "a deep RL run", resume)
        try:
            saved = json.loads(config_path.read_text())["config"]
        except (json.JSONDecodeError, KeyError, TypeError):
            raise BrlInputError(f"{config_path} is not a brl deep RL configuration") from None
        refuse_existing(run_dir, "a deep RL run", resume, DeepRLConfig.from_dict(saved) == cfg)


def train_deep_rl(cfg: DeepRLConfig, run_dir: Path, resume: bool = False,
                  progress: Callable[[DeepRLProgress], None] | None = None,
                  evaluator: Evaluator | None = None) -> dict[str, Any]:
    """Train the deep RL baseline for `cfg.steps` env steps, evaluating with `evaluator` (on
    `cfg.evaluation_suite`, e.g. `brlcli.bench.runner.suite_evaluator`) every `cfg.eval_every`; resumable. The
    evaluator is closed at the end."""
    from stable_baselines3.common.callbacks import BaseCallback

    if (evaluator is None) != (cfg.evaluation_suite == "none"):
        raise ValueError(f"evaluation suite {cfg.evaluation_suite} needs an evaluator (and 'none' none)")

    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    check_run_dir(cfg, run_dir, resume)
    labeler_for(cfg.input, cfg.segnet, "--input")  # a bad segmentation net fails before anything is written
    if (run_dir / "summary.json").exists():
        return json.loads((run_dir / "summary.json").read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(config_path, provenance(cfg.to_dict(), kind="train-rl"))
    torch.set_num_threads(1)
    env = _make_env(cfg)
    model = _build_dqn(cfg, env)
    state = _load_checkpoint(run_dir, model) if resume else None
    chunk = state["chunk"] if state else 0
    curve: list[dict] = state["curve"] if state else []
    wall0 = state["wall_s"] if state else 0.0
    eval_s = state["eval_s"] if state else 0.0
    t0 = time.perf_counter()
    setting = f"{cfg.algo.upper()}-{setting_name(cfg.input, cfg.input)}"
    n_chunks = -(-cfg.steps // cfg.eval_every)

    class _Hooks(BaseCallback):
        def _on_training_start(self) -> None:
            self.model._total_timesteps = cfg.steps  # exploration schedule over the whole budget, not the chunk

        def _on_step(self) -> bool:
            if progress and self.model.num_timesteps % 250 == 0:
                progress(DeepRLProgress(self.model.num_timesteps, cfg.steps, self.model._episode_num,
                                        float(self.model.exploration_rate)))
            return True

    try:
        while chunk < n_chunks:
            steps = min(cfg.eval_every, cfg.steps - chunk * cfg.eval_every)
            model._last_obs = None  # every chunk starts from a fresh, seeded reset: resumable bit for bit
            model.set_random_seed(_chunk_seed(cfg.seed, chunk))
            model.learn(total_timesteps=steps, reset_num_timesteps=False, callback=_Hooks())
            chunk += 1
            q_net = model.q_net.q_net
            save_model(run_dir / "drl.pt", q_net, cfg, int(model.num_timesteps))
            if evaluator is not None:
                t_eval = time.perf_counter()
                if cfg.task == "navigation":
                    pol = StatePolicy("dqn", setting, greedy_command_action_fn(q_net), env.unwrapped.labeler,
                                      cfg.camera(), uses_command=True, actions=cfg.actions)
                else:
                    pol = StatePolicy("dqn", setting, greedy_action_fn(q_net), env.labeler, cfg.camera(),
                                      actions=cfg.actions)
                curve.append({"env_steps": int(model.num_timesteps), **evaluator.evaluate(pol)})
                write_curve(run_dir / CURVE_FILE, curve)
                eval_s += time.perf_counter() - t_eval
            _save_checkpoint(run_dir, model, chunk, curve, wall0 + time.perf_counter() - t0, eval_s)
            if progress:
                progress(DeepRLProgress(int(model.num_timesteps), cfg.steps, model._episode_num,
                                        float(model.exploration_rate), curve[-1]["success"] if curve else None))
    finally:
        env.close()
        if evaluator is not None:
            evaluator.close()
    wall = wall0 + time.perf_counter() - t0
    learn_s = wall - eval_s
    summary = {"env_steps": int(model.num_timesteps), "episodes": int(model._episode_num), "wall_s": wall,
               "eval_s": eval_s, "steps_per_s": model.num_timesteps / learn_s if learn_s > 0 else float("nan"),
               "final_eval": curve[-1] if curve else None, "setting": setting}
    atomic_write_json(run_dir / "summary.json", {**provenance(cfg.to_dict()), "summary": summary})
    if progress:
        progress(DeepRLProgress(int(model.num_timesteps), cfg.steps, model._episode_num,
                                float(model.exploration_rate), curve[-1]["success"] if curve else None, done=True))
    return {**provenance(cfg.to_dict()), "summary": summary}
