"""Recording to ROS 2 bags and replaying them."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from brlcli.bags import (
    TOPIC_LABELS,
    TOPIC_RGB,
    EpisodeBagWriter,
    bag_metadata,
    find_bags,
    iter_frames,
    typestore,
)
from brlcli.collect import CollectConfig, collect
from brlcli.errors import BrlInputError
from brlcli.features import state_vector
from brlcli.sim import Control, World


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, list]:
    """A 40-frame bag written from a live drive, with the live frames kept for comparison."""
    out = tmp_path_factory.mktemp("bags")
    world = World("town02", weather=6, vehicles=3, pedestrians=5)
    frame = world.reset(world.town.training_routes[0].start, seed=1)
    writer = EpisodeBagWriter(out / "episode_00000", {"brl.town": "town02", "brl.weather": 6})
    live = []
    for i in range(40):
        frame = world.step(Control(steer=0.05 * np.sin(i / 5), throttle=0.5))
        writer.write(frame)
        live.append(frame)
    writer.close()
    world.close()
    return out, live


def test_bag_opens_with_anyreader_and_images_decode_to_the_rendered_arrays(recorded) -> None:
    out, live = recorded
    with AnyReader([out / "episode_00000"], default_typestore=typestore()) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert {TOPIC_RGB, TOPIC_LABELS, "/camera/depth", "/measurements", "/control"} <= set(topics)
        assert topics[TOPIC_RGB].msgtype == "sensor_msgs/msg/Image"
        msgs = list(reader.messages(connections=[topics[TOPIC_RGB]]))
        assert len(msgs) == 40
        img = reader.deserialize(msgs[7][2], "sensor_msgs/msg/Image")
        assert img.encoding == "rgb8"
        np.testing.assert_array_equal(np.asarray(img.data).reshape(img.height, img.width, 3), live[7].rgb)
        meas = list(reader.messages(connections=[topics["/measurements"]]))
        m = reader.deserialize(meas[7][2], "brl_msgs/msg/Measurements")
        assert m.forward_speed_kmh == live[7].measurements.forward_speed_kmh


def test_replay_gives_the_live_frames_and_features(recorded) -> None:
    out, live = recorded
    frames = list(iter_frames([out], depth=True))
    assert len(frames) == 40
    for rec, ref in zip(frames, live, strict=True):
        np.testing.assert_array_equal(rec.rgb, ref.rgb)
        np.testing.assert_array_equal(rec.labels, ref.labels)
        np.testing.assert_array_equal(rec.depth, ref.depth)
        assert rec.measurements == ref.measurements
        np.testing.assert_array_equal(state_vector(rec.labels), state_vector(ref.labels))
    meta = bag_metadata(out / "episode_00000")
    assert meta["brl.town"] == "town02" and meta["brl.weather"] == "6" and "brl.version" in meta


def test_collect_is_resumable_after_an_interruption(tmp_path: Path) -> None:
    cfg = CollectConfig(town="town02", weathers=(1, 8), episodes=3, episode_frames=15, seed=3)

    class Stop(Exception):
        pass

    def stop_in_second_episode(episode: int, recorded: int, fps: float) -> None:
        if episode == 1:
            raise Stop

    with pytest.raises(Stop):
        collect(cfg, tmp_path / "cut", progress=stop_in_second_episode)
    assert [p.name for p in find_bags([tmp_path / "cut"])] == ["episode_00000"]
    assert len(list(iter_frames([tmp_path / "cut"]))) == 15  # the finished episode stays readable
    with pytest.raises(BrlInputError):
        collect(cfg, tmp_path / "cut")  # needs --resume
    collect(cfg, tmp_path / "cut", resume=True)
    collect(cfg, tmp_path / "full")
    cut, full = list(iter_frames([tmp_path / "cut"])), list(iter_frames([tmp_path / "full"]))
    assert len(cut) == len(full) == 45
    for a, b in zip(cut, full, strict=True):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        assert a.measurements == b.measurements and a.control == b.control
    assert bag_metadata(tmp_path / "full" / "episode_00001")["brl.weather"] == "8"


def test_sqlite3_storage_reads_back(tmp_path: Path) -> None:
    collect(CollectConfig(town="town02", episodes=1, episode_frames=5, storage="sqlite3"), tmp_path)
    assert list((tmp_path / "episode_00000").glob("*.db3"))
    assert len(list(iter_frames([tmp_path]))) == 5


def test_bad_bags_are_clear_errors(tmp_path: Path, recorded) -> None:
    out, _ = recorded
    with pytest.raises(BrlInputError, match="does not exist"):
        list(iter_frames([tmp_path / "missing"]))
    with pytest.raises(BrlInputError, match="matches no files"):
        list(iter_frames([str(tmp_path / "nothing*")]))
    corrupt = tmp_path / "corrupt"
    shutil.copytree(out / "episode_00000", corrupt)
    mcap = next(corrupt.glob("*.mcap"))
    mcap.write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 100)
    with pytest.raises(BrlInputError):
        list(iter_frames([corrupt]))
    # a bag with RGB only
    store = typestore()
    rgb_only = tmp_path / "rgb_only"
    with Writer(rgb_only, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection(TOPIC_RGB, "sensor_msgs/msg/Image", typestore=store)
        t = store.types
        msg = t["sensor_msgs/msg/Image"](header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=0, nanosec=0), frame_id="camera"), height=2, width=2, encoding="rgb8", is_bigendian=0, step=6,
            data=np.zeros(12, np.uint8))
        w.write(conn, 0, store.serialize_cdr(msg, "sensor_msgs/msg/Image"))
    with pytest.raises(BrlInputError, match="no label images"):
        list(iter_frames([rgb_only]))


def test_collect_cli_writes_bags_and_rejects_bad_input(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "brlcli.cli", "collect", "--town", "town02", "--episodes", "2",
           "--episode-frames", "5", "--weathers", "1,WetNoon", "--out", str(tmp_path / "ok")]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert len(find_bags([tmp_path / "ok"])) == 2
    for bad in (["--weathers", "Snow"], ["--storage", "parquet"], ["--episodes", "0"], ["--town", "town5"],
                ["--excursions", "0.1", "--traffic"], ["--excursions", "-1"]):
        r = subprocess.run([sys.executable, "-m", "brlcli.cli", "collect", "--out", str(tmp_path / "bad"), *bad],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, (bad, r.stderr)
        assert not (tmp_path / "bad").exists()


def test_excursions_take_the_car_off_its_lane_and_back(tmp_path: Path) -> None:
    cfg = CollectConfig(town="town01", weathers=(1,), episodes=2, episode_frames=200, every=2, seed=4,
                        excursions=0.2, depth=False)
    collect(cfg, tmp_path / "exc")
    frames = list(iter_frames([tmp_path / "exc"]))
    off = np.array([max(f.measurements.intersection_offroad, f.measurements.intersection_otherlane) for f in frames])
    assert (off > 0.5).mean() > 0.15 and (off < 0.05).mean() > 0.2  # beside the lane, and back in it
    applied = np.array([f.control.steer for f in frames])
    expert = np.array([f.expert_control.steer for f in frames])
    assert np.abs(applied - expert).max() > 0.1  # the recorded expert control is the clean one
    assert np.median([f.measurements.forward_speed_kmh for f in frames]) > 5.0  # not stuck
    # a recording without excursions keeps brl 0.1's configuration
    assert "excursions" not in CollectConfig().to_dict() and CollectConfig(excursions=0.1).to_dict()["excursions"]
