"""`--device` (issue 36): names, the device-side batch code (exercised on CPU tensors), and CUDA runs where a GPU is."""

from pathlib import Path

import numpy as np
import pytest
import torch

from brlcli.devices import check_device_name, resolve_device
from brlcli.errors import BrlInputError

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def test_device_names_resolve_or_fail_in_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    assert resolve_device("cpu") == "cpu" and resolve_device(" CPU ") == "cpu"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    for bad, message in (("cuda", "use --device cpu"), ("cuda:0", "use --device cpu"), ("tpu", "is not a device"),
                         ("cuda:x", "is not a device")):
        with pytest.raises(BrlInputError, match=message):
            resolve_device(bad)
    check_device_name("cuda:1")
    with pytest.raises(BrlInputError, match="must be auto, cpu, cuda or cuda:N"):
        check_device_name("gpu")


def test_device_names_are_checked_in_every_training_config() -> None:
    from brlcli.baselines.deeprl import DeepRLConfig
    from brlcli.baselines.il import ILTrainConfig
    from brlcli.segnet.train import SegTrainConfig

    for cls in (SegTrainConfig, ILTrainConfig, DeepRLConfig):
        assert cls().device == "cpu" and cls().to_dict()["device"] == "cpu"  # recorded in config.json
        with pytest.raises(BrlInputError, match="--device must be"):
            cls(device="gpu")


def test_the_device_batch_flips_images_and_labels_together_and_counts_presence() -> None:
    from brlcli.segnet.train import SegTrainConfig, _device_batch, presence_targets

    rng = np.random.default_rng(0)
    rgb = torch.from_numpy(rng.integers(0, 256, (6, 4, 5, 3), dtype=np.uint8))
    labels = torch.from_numpy(rng.integers(0, 13, (6, 4, 5), dtype=np.uint8))
    cfg = SegTrainConfig(colour_jitter=0.0)
    mean, std = torch.zeros(3), torch.ones(3)
    x, y, present = _device_batch(rgb, labels, np.arange(6), torch.Generator().manual_seed(1), cfg, mean, std)
    assert x.shape == (6, 3, 4, 5) and y.dtype == torch.int64 and present.shape == (6, 13)
    back = (x.permute(0, 2, 3, 1) * 255.0).round().to(torch.uint8)
    for i in range(6):  # every image is either as it was or mirrored, and its labels with it
        flipped = not torch.equal(back[i], rgb[i])
        assert torch.equal(back[i], rgb[i].flip(1) if flipped else rgb[i])
        assert torch.equal(y[i], (labels[i].flip(1) if flipped else labels[i]).long())
    assert np.array_equal(present.numpy(), presence_targets(y.numpy()))


def test_device_colour_jitter_stays_in_range_and_follows_its_generator() -> None:
    from brlcli.baselines.il import augment_on_device as il_augment
    from brlcli.segnet.train import SegTrainConfig, augment_on_device

    rgb = torch.full((4, 3, 3, 3), 200, dtype=torch.uint8)
    labels = torch.zeros((4, 3, 3), dtype=torch.uint8)
    cfg = SegTrainConfig(colour_jitter=0.25)
    a, _ = augment_on_device(rgb, labels, torch.Generator().manual_seed(3), cfg)
    b, _ = augment_on_device(rgb, labels, torch.Generator().manual_seed(3), cfg)
    assert torch.equal(a, b) and float(a.min()) >= 0 and float(a.max()) <= 255 and not torch.equal(a, rgb.float())
    c = il_augment(rgb, torch.Generator().manual_seed(3), 0.2)
    assert float(c.min()) >= 0 and float(c.max()) <= 255 and c.shape == rgb.shape


@CUDA
def test_segnet_trains_on_cuda_and_loads_on_the_cpu(tmp_path: Path) -> None:
    from brlcli.segnet.io import load_segnet
    from brlcli.segnet.train import SegTrainConfig, train_segnet
    from tests.test_segnet import TINY, _frames

    frames = _frames()
    cfg = SegTrainConfig(epochs=2, batch_size=8, threads=1, net=TINY, device="cuda")
    a = train_segnet(frames, {"val": frames[:8]}, cfg, tmp_path / "a")
    b = train_segnet(frames, {"val": frames[:8]}, cfg, tmp_path / "b")
    assert a["history"][-1]["loss"] == pytest.approx(b["history"][-1]["loss"], rel=1e-3)
    net, _ = load_segnet(tmp_path / "a" / "segnet.pt")
    assert all(p.device.type == "cpu" for p in net.parameters())


@CUDA
def test_deep_rl_config_takes_cuda() -> None:
    from brlcli.baselines.deeprl import DeepRLConfig

    assert DeepRLConfig(device="cuda").device == "cuda"
