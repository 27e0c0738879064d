"""Recording frames to ROS 2 bags (rosbags) and replaying them.

One bag per episode, written under a hidden `.partial` name and renamed when closed, so an interrupted recording
leaves every finished episode readable and no half-written bag under a real name. Topics (one timestamp per frame):

    /camera/rgb      sensor_msgs/msg/Image  rgb8
    /camera/labels   sensor_msgs/msg/Image  mono8   CARLA 0.8 class ids
    /camera/depth    sensor_msgs/msg/Image  32FC1   planar depth, metres
    /measurements    brl_msgs/msg/Measurements      CARLA measurement names
    /control         brl_msgs/msg/Control           applied and expert controls, route command

The custom message definitions are embedded in the bag (MCAP schemas / sqlite3 metadata), so any ROS 2 tool
or `rosbags.highlevel.AnyReader` can decode them without brl.
"""

from __future__ import annotations

import glob
import json
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from brlcli import __version__
from brlcli.errors import BrlInputError
from brlcli.provenance import git_commit
from brlcli.sim.vehicle import Control
from brlcli.sim.world import Frame, Measurements

BAG_FORMAT_VERSION = 1
TOPIC_RGB = "/camera/rgb"
TOPIC_LABELS = "/camera/labels"
TOPIC_DEPTH = "/camera/depth"
TOPIC_MEASUREMENTS = "/measurements"
TOPIC_CONTROL = "/control"
FRAME_ID = "camera"

MEASUREMENTS_MSG = """std_msgs/Header header
float64 forward_speed_kmh
float64 x
float64 y
float64 yaw_deg
float64 game_time_s
float64 collision_vehicles
float64 collision_pedestrians
float64 collision_other
float64 intersection_offroad
float64 intersection_otherlane
"""
CONTROL_MSG = """std_msgs/Header header
float64 steer
float64 throttle
float64 brake
bool reverse
float64 expert_steer
float64 expert_throttle
float64 expert_brake
bool expert_reverse
uint8 command
"""
MEASUREMENTS_TYPE = "brl_msgs/msg/Measurements"
CONTROL_TYPE = "brl_msgs/msg/Control"
IMAGE_TYPE = "sensor_msgs/msg/Image"

_MEASUREMENT_FIELDS = tuple(Measurements.__dataclass_fields__)


def typestore() -> Any:
    """ROS 2 Humble types plus brl's custom messages."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    types.update(get_types_from_msg(MEASUREMENTS_MSG, MEASUREMENTS_TYPE))
    types.update(get_types_from_msg(CONTROL_MSG, CONTROL_TYPE))
    store.register(types)
    return store


@dataclass(frozen=True)
class RecordedFrame:
    """A frame read back from a bag."""

    timestamp_ns: int
    rgb: np.ndarray | None
    labels: np.ndarray | None
    depth: np.ndarray | None
    measurements: Measurements | None
    control: Control | None
    expert_control: Control | None
    command: int | None
    bag: str


class EpisodeBagWriter:
    """Writes one episode's frames to a bag; `close()` publishes it under its final name, `abort()` removes it."""

    def __init__(self, path: Path, metadata: dict[str, Any], storage: str = "mcap", depth: bool = True) -> None:
        if storage not in ("mcap", "sqlite3"):
            raise BrlInputError(f"--storage must be mcap or sqlite3, not '{storage}'")
        self.path = Path(path)
        # written inside a hidden staging directory, then moved: the storage file keeps the bag's own name
        self.partial = self.path.parent / ".partial" / self.path.name
        if self.partial.exists():
            shutil.rmtree(self.partial)
        self.partial.parent.mkdir(parents=True, exist_ok=True)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._store = typestore()
        self._writer = Writer(self.partial, version=9, storage_plugin=plugin)
        if storage == "mcap":  # zstd-compressed MCAP chunks
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        else:
            self._writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
        self._writer.open()
        for key, value in {**metadata, "brl.bag_format_version": BAG_FORMAT_VERSION, "brl.version": __version__,
                           "brl.git_commit": git_commit()}.items():
            self._writer.set_custom_data(key, value if isinstance(value, str) else json.dumps(value))
        s = self._store
        self._conn = {
            TOPIC_RGB: self._writer.add_connection(TOPIC_RGB, IMAGE_TYPE, typestore=s),
            TOPIC_LABELS: self._writer.add_connection(TOPIC_LABELS, IMAGE_TYPE, typestore=s),
            TOPIC_MEASUREMENTS: self._writer.add_connection(TOPIC_MEASUREMENTS, MEASUREMENTS_TYPE, typestore=s),
            TOPIC_CONTROL: self._writer.add_connection(TOPIC_CONTROL, CONTROL_TYPE, typestore=s),
        }
        if depth:
            self._conn[TOPIC_DEPTH] = self._writer.add_connection(TOPIC_DEPTH, IMAGE_TYPE, typestore=s)
        t = s.types
        self._Image, self._Header = t[IMAGE_TYPE], t["std_msgs/msg/Header"]
        self._Time = t["builtin_interfaces/msg/Time"]
        self._Meas, self._Ctl = t[MEASUREMENTS_TYPE], t[CONTROL_TYPE]
        self.frames = 0

    def _image(self, header: Any, arr: np.ndarray, encoding: str) -> bytes:
        h, w = arr.shape[:2]
        data = np.ascontiguousarray(arr).view(np.uint8).reshape(-1)
        msg = self._Image(header=header, height=h, width=w, encoding=encoding, is_bigendian=0,
                          step=data.size // h, data=data)
        return self._store.serialize_cdr(msg, IMAGE_TYPE)

    def write(self, frame: Frame, expert: Control | None = None, command: int = 0) -> None:
        """Append one rendered frame (its game time is the timestamp)."""
        if frame.rgb is None or frame.labels is None:
            raise ValueError("only rendered frames can be recorded")
        ts = round(frame.measurements.game_time_s * 1e9)
        header = self._Header(stamp=self._Time(sec=ts // 10**9, nanosec=ts % 10**9), frame_id=FRAME_ID)
        w = self._writer
        w.write(self._conn[TOPIC_RGB], ts, self._image(header, frame.rgb, "rgb8"))
        w.write(self._conn[TOPIC_LABELS], ts, self._image(header, frame.labels, "mono8"))
        if TOPIC_DEPTH in self._conn and frame.depth is not None:
            w.write(self._conn[TOPIC_DEPTH], ts, self._image(header, frame.depth.astype("<f4"), "32FC1"))
        m = frame.measurements
        meas = self._Meas(header=header, **{k: float(getattr(m, k)) for k in _MEASUREMENT_FIELDS})
        w.write(self._conn[TOPIC_MEASUREMENTS], ts, self._store.serialize_cdr(meas, MEASUREMENTS_TYPE))
        c, e = frame.control, expert or frame.control
        ctl = self._Ctl(header=header, steer=c.steer, throttle=c.throttle, brake=c.brake, reverse=c.reverse,
                        expert_steer=e.steer, expert_throttle=e.throttle, expert_brake=e.brake,
                        expert_reverse=e.reverse, command=int(command))
        w.write(self._conn[TOPIC_CONTROL], ts, self._store.serialize_cdr(ctl, CONTROL_TYPE))
        self.frames += 1

    def close(self) -> Path:
        """Finish the bag and move it to its final name."""
        self._writer.close()
        if self.path.exists():
            shutil.rmtree(self.path)
        self.partial.rename(self.path)
        try:
            self.partial.parent.rmdir()
        except OSError:
            pass
        return self.path

    def abort(self) -> None:
        """Drop the unfinished bag."""
        try:
            self._writer.close()
        except Exception:
            pass
        shutil.rmtree(self.partial, ignore_errors=True)


def find_bags(inputs: Sequence[str | Path]) -> list[Path]:
    """Bag directories from paths (a bag, or a directory holding bags) and globs; finished bags only, sorted."""
    found: list[Path] = []
    for item in inputs:
        text = str(item)
        paths = sorted(Path(p) for p in glob.glob(text)) if any(ch in text for ch in "*?[") else [Path(text)]
        if not paths:
            raise BrlInputError(f"'{text}' matches no files")
        for p in paths:
            if not p.exists():
                raise BrlInputError(f"{p} does not exist")
            if (p / "metadata.yaml").exists():
                found.append(p)
            elif p.is_dir():
                subs = sorted(q.parent for q in p.glob("*/metadata.yaml") if not q.parent.name.startswith("."))
                if not subs:
                    raise BrlInputError(f"{p} holds no ROS 2 bags (no */metadata.yaml)")
                found.extend(subs)
            else:
                raise BrlInputError(f"{p} is not a ROS 2 bag directory (no metadata.yaml)")
    return sorted(dict.fromkeys(found))


def _decode_image(msg: Any) -> np.ndarray:
    dtype, channels = {"rgb8": (np.uint8, 3), "mono8": (np.uint8, 1), "32FC1": (np.dtype("<f4"), 1)}[msg.encoding]
    arr = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dtype)
    shape = (msg.height, msg.width, channels) if channels > 1 else (msg.height, msg.width)
    return arr.reshape(shape)


def bag_metadata(path: str | Path) -> dict[str, str]:
    """The custom data (brl.town, brl.weather, brl.seed, brl.camera, brl.version, ...) of a bag's metadata.yaml."""
    from ruamel.yaml import YAML

    meta = Path(path) / "metadata.yaml"
    try:
        doc = YAML(typ="safe").load(meta.read_text())
        return dict(doc["rosbag2_bagfile_information"].get("custom_data") or {})
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise BrlInputError(f"cannot read bag metadata {meta}: {exc}".splitlines()[0]) from None


def iter_frames(bags: Sequence[str | Path], need_labels: bool = True, depth: bool = False) -> Iterator[RecordedFrame]:
    """Frames of one or many bags, in bag then time order (RGB, labels, optional depth, measurements, control)."""
    paths = find_bags(bags)
    store = typestore()
    topics = {TOPIC_RGB, TOPIC_LABELS, TOPIC_MEASUREMENTS, TOPIC_CONTROL} | ({TOPIC_DEPTH} if depth else set())
    for path in paths:
        try:
            reader = AnyReader([path], default_typestore=store)
            reader.open()
        except Exception as exc:
            raise BrlInputError(f"cannot read bag {path}: {exc}".splitlines()[0]) from None
        try:
            conns = [c for c in reader.connections if c.topic in topics]
            present = {c.topic for c in conns}
            if need_labels and TOPIC_LABELS not in present:
                raise BrlInputError(f"bag {path} has no label images ({TOPIC_LABELS}); record it with brl collect")
            if TOPIC_RGB not in present:
                raise BrlInputError(f"bag {path} has no RGB images ({TOPIC_RGB})")
            pending: dict[int, dict[str, Any]] = {}
            expected = present
            try:
                for conn, ts, raw in reader.messages(connections=conns):
                    msg = reader.deserialize(raw, conn.msgtype)
                    slot = pending.setdefault(ts, {})
                    slot[conn.topic] = msg
                    if set(slot) >= expected:
                        yield _assemble(pending.pop(ts), ts, str(path))
            except BrlInputError:
                raise
            except Exception as exc:
                raise BrlInputError(f"bag {path} is corrupt: {exc}".splitlines()[0]) from None
        finally:
            reader.close()


def _assemble(slot: dict[str, Any], ts: int, bag: str) -> RecordedFrame:
    meas = slot.get(TOPIC_MEASUREMENTS)
    ctl = slot.get(TOPIC_CONTROL)
    return RecordedFrame(
        timestamp_ns=ts,
        rgb=_decode_image(slot[TOPIC_RGB]) if TOPIC_RGB in slot else None,
        labels=_decode_image(slot[TOPIC_LABELS]) if TOPIC_LABELS in slot else None,
        depth=_decode_image(slot[TOPIC_DEPTH]) if TOPIC_DEPTH in slot else None,
        measurements=Measurements(**{k: float(getattr(meas, k)) for k in _MEASUREMENT_FIELDS}) if meas else None,
        control=Control(ctl.steer, ctl.throttle, ctl.brake, bool(ctl.reverse)) if ctl else None,
        expert_control=Control(ctl.expert_steer, ctl.expert_throttle, ctl.expert_brake, bool(ctl.expert_reverse))
        if ctl else None,
        command=int(ctl.command) if ctl else None,
        bag=bag,
    )
