"""An EncNet-style segmentation net (Zhang et al., CVPR 2018) sized for a CPU, in plain torch.

Backbone: a small dilated ResNet (hand-written BasicBlocks, output stride 8). Head: the Context Encoding Module
(1x1 conv + BN + ReLU, an Encoding layer with K codewords and smoothing factors, BatchNorm1d over K + ReLU, mean
over codewords, channel attention `relu(x + x * sigmoid(FC(e)))`), a Semantic Encoding branch `FC(e)` predicting
which classes are present, an auxiliary FCN head on stage 3, and a light skip from stage 1 (output stride 4) so
that thin classes (road lines, poles) survive the upsampling. With `fine` > 0 a second refinement at output stride 2
(the stem's first features) sharpens the boundaries of thin classes, whose area the 30-number state weighs by 20.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

NUM_CLASSES = 13


@dataclass(frozen=True)
class SegNetConfig:
    """Widths of the net (channels) and the Encoding layer's codeword count."""

    stem: int = 16
    widths: tuple[int, int, int, int] = (32, 64, 64, 96)
    enc_channels: int = 64
    codewords: int = 32
    num_classes: int = NUM_CLASSES
    fine: int = 0  # channels of the output-stride-2 refinement (0: none, the net of brl 0.1)

    def to_dict(self) -> dict:
        """Plain-data form (stored in checkpoints)."""
        d = asdict(self)
        d["widths"] = list(self.widths)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> SegNetConfig:
        """Inverse of `to_dict`."""
        d = dict(d)
        d["widths"] = tuple(d["widths"])
        return cls(**d)


def conv_bn_relu(cin: int, cout: int, k: int = 3, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    """Convolution, batch norm, ReLU."""
    pad = dilation * (k // 2)
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, pad, dilation=dilation, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet basic block with optional stride and dilation (torchvision's refuses dilation > 1)."""

    def __init__(self, cin: int, cout: int, stride: int = 1, dilation: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, dilation, dilation=dilation, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Residual block."""
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.down is None else self.down(x)), inplace=True)


class Encoding(nn.Module):
    """EncNet's Encoding layer: soft-assign features to K codewords and aggregate the residuals.

    `A_ik = softmax_k(s_k ||x_i - c_k||^2)`, `e_k = sum_i A_ik (x_i - c_k)`; distances in the memory-light form
    `|x|^2 - 2 x C^T + |C|^2`, aggregation by matrix products.
    """

    def __init__(self, channels: int, codewords: int) -> None:
        super().__init__()
        std = 1.0 / (codewords * channels) ** 0.5
        self.codewords = nn.Parameter(torch.empty(codewords, channels).uniform_(-std, std))
        self.scale = nn.Parameter(torch.empty(codewords).uniform_(-1.0, 0.0))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, D, H, W) features -> (B, K, D) encoded residuals."""
        b, d = x.shape[:2]
        feats = x.reshape(b, d, -1).transpose(1, 2)  # (B, N, D)
        c = self.codewords
        dist = (feats * feats).sum(-1, keepdim=True) - 2.0 * feats @ c.t() + (c * c).sum(-1)[None, None, :]
        assign = torch.softmax(dist * self.scale[None, None, :], dim=2)  # (B, N, K)
        return assign.transpose(1, 2) @ feats - assign.sum(1)[:, :, None] * c[None]


class EncModule(nn.Module):
    """Context Encoding Module with channel attention and the Semantic Encoding (presence) head."""

    def __init__(self, cin: int, channels: int, codewords: int, num_classes: int) -> None:
        super().__init__()
        self.reduce = conv_bn_relu(cin, channels, k=1)
        self.encoding = Encoding(channels, codewords)
        self.bn = nn.BatchNorm1d(codewords)
        self.attention = nn.Linear(channels, channels)
        self.presence = nn.Linear(channels, num_classes)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features re-weighted by context, and class-presence logits."""
        x = self.reduce(x)
        e = F.relu(self.bn(self.encoding(x)), inplace=True).mean(dim=1)  # (B, D)
        gamma = torch.sigmoid(self.attention(e))[:, :, None, None]
        return F.relu(x + x * gamma), self.presence(e)


class SegNet(nn.Module):
    """EncNet-style segmentation net; `forward` returns (logits, aux logits, presence logits) in training."""

    def __init__(self, cfg: SegNetConfig = SegNetConfig()) -> None:
        super().__init__()
        self.cfg = cfg
        w1, w2, w3, w4 = cfg.widths
        self.stem = nn.Sequential(conv_bn_relu(3, cfg.stem, stride=2), conv_bn_relu(cfg.stem, w1, stride=2))
        self.layer1 = BasicBlock(w1, w1)
        self.layer2 = BasicBlock(w1, w2, stride=2)
        self.layer3 = BasicBlock(w2, w3, dilation=2)
        self.layer4 = BasicBlock(w3, w4, dilation=4)
        self.enc = EncModule(w4, cfg.enc_channels, cfg.codewords, cfg.num_classes)
        self.head = conv_bn_relu(cfg.enc_channels, cfg.enc_channels)
        self.skip = conv_bn_relu(w1, cfg.enc_channels // 2, k=1)
        self.fuse = conv_bn_relu(cfg.enc_channels + cfg.enc_channels // 2, cfg.enc_channels)
        if cfg.fine:
            self.fine_proj = conv_bn_relu(cfg.enc_channels, cfg.fine, k=1)
            self.fine_fuse = conv_bn_relu(cfg.fine + cfg.stem, cfg.fine)
        self.classifier = nn.Sequential(nn.Dropout2d(0.1), nn.Conv2d(cfg.fine or cfg.enc_channels, cfg.num_classes, 1))
        self.aux = nn.Sequential(conv_bn_relu(w3, w3 // 2), nn.Conv2d(w3 // 2, cfg.num_classes, 1))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """Per-pixel class logits at input size (+ auxiliary and presence logits while training)."""
        size = x.shape[-2:]
        s0 = self.stem[0](x)
        s1 = self.layer1(self.stem[1](s0))
        s3 = self.layer3(self.layer2(s1))
        feats, presence = self.enc(self.layer4(s3))
        y = F.interpolate(self.head(feats), size=s1.shape[-2:], mode="bilinear", align_corners=False)
        y = self.fuse(torch.cat([y, self.skip(s1)], dim=1))
        if self.cfg.fine:
            y = F.interpolate(self.fine_proj(y), size=s0.shape[-2:], mode="bilinear", align_corners=False)
            y = self.fine_fuse(torch.cat([y, s0], dim=1))
        logits = F.interpolate(self.classifier(y), size=size, mode="bilinear", align_corners=False)
        if not self.training:
            return logits, None, None
        aux = F.interpolate(self.aux(s3), size=size, mode="bilinear", align_corners=False)
        return logits, aux, presence
