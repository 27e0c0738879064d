"""The EncNet-style segmentation net: Encoding layer, SE targets, IoU, training, files."""

from pathlib import Path

import numpy as np
import pytest
import torch

from brlcli.errors import BrlInputError
from brlcli.segnet.infer import Segmenter, uncalibrated_notice
from brlcli.segnet.io import SEGNET_FORMAT, load_segnet, save_checkpoint
from brlcli.segnet.metrics import category_confusion, confusion, iou_from_confusion
from brlcli.segnet.model import Encoding, SegNet, SegNetConfig
from brlcli.segnet.train import SegTrainConfig, presence_targets, train_segnet

TINY = SegNetConfig(stem=8, widths=(8, 16, 16, 16), enc_channels=16, codewords=4).to_dict()


def test_encoding_layer_equals_the_naive_formula() -> None:
    torch.manual_seed(0)
    enc = Encoding(channels=5, codewords=3)
    x = torch.randn(2, 5, 3, 4)
    got = enc(x)
    feats = x.reshape(2, 5, -1).transpose(1, 2)
    want = torch.zeros(2, 3, 5)
    for b in range(2):
        for i in range(feats.shape[1]):
            d = torch.stack([((feats[b, i] - enc.codewords[k]) ** 2).sum() for k in range(3)])
            a = torch.softmax(enc.scale * d, dim=0)
            for k in range(3):
                want[b, k] += a[k] * (feats[b, i] - enc.codewords[k])
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    assert (enc.scale < 0).all()  # smoothing factors start negative


def test_presence_targets_are_the_classes_in_each_image() -> None:
    labels = np.zeros((2, 4, 4), np.uint8)
    labels[0, 0, 0] = 7
    labels[1] = 12
    t = presence_targets(labels)
    assert t.shape == (2, 13)
    assert set(np.flatnonzero(t[0])) == {0, 7} and set(np.flatnonzero(t[1])) == {12}


def test_iou_per_class_and_per_category() -> None:
    truth = np.array([7, 7, 6, 8, 1, 1])
    pred = np.array([7, 6, 6, 8, 1, 9])
    cm = confusion(pred, truth, 13)
    iou = iou_from_confusion(cm)
    assert iou[7] == pytest.approx(1 / 2) and iou[6] == pytest.approx(1 / 2) and iou[8] == 1.0
    assert iou[1] == pytest.approx(1 / 2) and iou[9] == 0.0 and np.isnan(iou[4])
    cat = iou_from_confusion(category_confusion(cm))
    # categories: road {7}, road line {6}, off-road {8,3,0}, dynamic {4,10}, static {1,2,5,9,11,12}
    assert cat[0] == pytest.approx(1 / 2) and cat[1] == pytest.approx(1 / 2) and cat[2] == 1.0
    assert cat[4] == 1.0 and np.isnan(cat[3])


def _frames(n: int = 24) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):  # a road below a sky-and-building band, with noise: learnable in a few steps
        labels = np.zeros((32, 64), np.uint8)
        labels[:10] = 0
        labels[10:16] = 1
        labels[16:] = 7
        labels[16:, 30:33] = 6
        rgb = np.zeros((32, 64, 3), np.uint8)
        rgb[labels == 1] = (150, 120, 100)
        rgb[labels == 7] = (80, 80, 85)
        rgb[labels == 6] = (230, 220, 60)
        rgb[labels == 0] = (120, 170, 230)
        rgb = np.clip(rgb + rng.integers(-20, 20, rgb.shape), 0, 255).astype(np.uint8)
        out.append((rgb, labels))
    return out


def test_tiny_training_lowers_the_loss_and_is_deterministic(tmp_path: Path) -> None:
    frames = _frames()
    cfg = SegTrainConfig(epochs=3, batch_size=8, threads=1, net=TINY, lr=0.05)
    a = train_segnet(frames, {"val": frames[:8]}, cfg, tmp_path / "a")
    losses = [r["loss"] for r in a["history"]]
    assert losses[-1] < losses[0]
    b = train_segnet(frames, {"val": frames[:8]}, cfg, tmp_path / "b")
    assert a["history"] == [{**r, "wall_s": a["history"][i]["wall_s"]} for i, r in enumerate(b["history"])]
    net_a, _ = load_segnet(tmp_path / "a" / "last.pt", deployable=False)
    net_b, _ = load_segnet(tmp_path / "b" / "last.pt", deployable=False)
    for pa, pb in zip(net_a.state_dict().values(), net_b.state_dict().values(), strict=True):
        torch.testing.assert_close(pa, pb, atol=0, rtol=0)


def test_resume_continues_to_the_same_weights(tmp_path: Path) -> None:
    frames = _frames(16)
    full = SegTrainConfig(epochs=2, batch_size=8, threads=1, net=TINY)
    train_segnet(frames, {"val": frames[:8]}, full, tmp_path / "full")
    # interrupt after epoch 1 by raising from the progress callback, then resume
    with pytest.raises(KeyboardInterrupt):
        train_segnet(frames, {"val": frames[:8]}, full, tmp_path / "cut", progress=_stop_after_first)
    train_segnet(frames, {"val": frames[:8]}, full, tmp_path / "cut", resume=True)
    net_a, _ = load_segnet(tmp_path / "full" / "last.pt", deployable=False)
    net_b, _ = load_segnet(tmp_path / "cut" / "last.pt", deployable=False)
    for pa, pb in zip(net_a.state_dict().values(), net_b.state_dict().values(), strict=True):
        torch.testing.assert_close(pa, pb, atol=0, rtol=0)


def _stop_after_first(record: dict) -> None:
    if record["epoch"] == 1:
        raise KeyboardInterrupt


def _tiny_file(path: Path, offsets: list[float] | None = None, version: int | None = None) -> Path:
    torch.manual_seed(1)
    net = SegNet(SegNetConfig.from_dict(TINY)).eval()
    meta = {"mean": [0.5, 0.5, 0.5], "std": [0.2, 0.2, 0.2], "input_size": [32, 64]}
    if offsets is not None:
        meta["logit_offsets"] = offsets
    save_checkpoint(path, net, meta)
    if version is not None:
        torch.save({**torch.load(path, weights_only=True), "format_version": version}, path)
    return path


def test_files_round_trip_and_bad_files_are_clear_errors(tmp_path: Path) -> None:
    _tiny_file(tmp_path / "n.pt", offsets=[0.0] * 13)
    seg = Segmenter(tmp_path / "n.pt")
    rgb = _frames(1)[0][0]
    labels = seg.predict(rgb)
    assert labels.shape == (32, 64) and labels.dtype == np.uint8 and seg.calibrated
    again = Segmenter(tmp_path / "n.pt").predict(rgb)
    np.testing.assert_array_equal(labels, again)
    with pytest.raises(BrlInputError, match="expects 64x32"):
        seg.predict(np.zeros((88, 200, 3), np.uint8))
    doc = torch.load(tmp_path / "n.pt", weights_only=True)
    assert doc["format"] == SEGNET_FORMAT and doc["format_version"] == 2
    for name, change in (("version", {"format_version": 99}), ("format", {"format": "other"})):
        torch.save({**doc, **change}, tmp_path / f"{name}.pt")
        with pytest.raises(BrlInputError):
            load_segnet(tmp_path / f"{name}.pt")
    missing = {k: v for k, v in doc.items() if k != "state_dict"}
    torch.save(missing, tmp_path / "missing.pt")
    with pytest.raises(BrlInputError, match="state_dict"):
        load_segnet(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(BrlInputError):
        load_segnet(tmp_path / "junk.pt")
    with pytest.raises(BrlInputError, match="does not exist"):
        load_segnet(tmp_path / "absent.pt")
    torch.save({**doc, "extra": {**doc["extra"], "logit_offsets": [0.0] * 5}}, tmp_path / "short.pt")
    with pytest.raises(BrlInputError, match="malformed calibration"):
        load_segnet(tmp_path / "short.pt")


def test_calibration_is_required_of_new_files_and_optional_for_old_ones(tmp_path: Path) -> None:
    _tiny_file(tmp_path / "uncal.pt")  # a format-2 training checkpoint: no offsets
    with pytest.raises(BrlInputError, match=r"no calibration.*brl calibrate-seg"):
        load_segnet(tmp_path / "uncal.pt")
    _, meta = load_segnet(tmp_path / "uncal.pt", deployable=False)
    assert meta["logit_offsets"] is None
    _tiny_file(tmp_path / "v1.pt", version=1)  # brl 0.1's files load, as uncalibrated nets
    seg = Segmenter(tmp_path / "v1.pt")
    assert not seg.calibrated and seg.predict(_frames(1)[0][0]).shape == (32, 64)
    assert "uncalibrated" in uncalibrated_notice(tmp_path / "v1.pt")
    _tiny_file(tmp_path / "v2.pt", offsets=[0.0] * 13)
    assert uncalibrated_notice(tmp_path / "v2.pt") is None


def test_logit_offsets_change_the_labels_and_both_backends_agree(tmp_path: Path) -> None:
    rgb = _frames(1)[0][0]
    base = Segmenter(_tiny_file(tmp_path / "a.pt", offsets=[0.0] * 13)).predict(rgb)
    push = [0.0] * 13
    push[6] = 1e4  # road line wins everywhere
    forced = Segmenter(_tiny_file(tmp_path / "b.pt", offsets=push)).predict(rgb)
    assert (forced == 6).all() and not (base == 6).all()
    for path in (tmp_path / "a.pt", tmp_path / "b.pt"):
        frames = _frames(6)
        fast, ref = Segmenter(path), Segmenter(path, backend="torch")
        for rgb_i, _ in frames:
            np.testing.assert_array_equal(fast.predict(rgb_i), ref.predict(rgb_i))
    with pytest.raises(BrlInputError, match="backend"):
        Segmenter(tmp_path / "a.pt", backend="tpu")
