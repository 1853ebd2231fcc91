"""The Tactus touch encoder in one file: per-frame ResNet trunk, 1x1 frame fusion, projector.

    frames (B, K, 32, 32) float32, calibrated to [0, 1]
      -> trunk, shared over frames          (B*K, C, h, w)
      -> concat the K maps on channels      (B, K*C, h, w)
      -> 1x1 conv + BN + ReLU (fusion)      (B, C, h, w)
      -> global average pool                (B, C)
      -> projector Linear-GELU-Linear       (B, D)
      -> L2 normalise                       (B, D) unit rows in the frozen text space

Models are built by name from small JSON configs in ``tactus_memory/touch/configs/``
(open_clip style): ``create_model("tactus-lite", out_dim=384)``.

Windows shorter than the model's K are padded by repeating their last frame, exactly as the
paper's inference-time K-sweep does, so the trained fusion layer always sees K slots.
Windows longer than K raise ``ValueError``: silently truncating would drop contacts the
caller meant to include; callers that want truncation slice ``frames[:, :K]`` themselves.

Stem choice: a 32x32 pressure map has no redundancy to throw away, so the paper's ResNet-18
(``tactus-r18``) uses a 3x3 stride-1 stem and no max-pool; stages run at 32, 16, 8, 4 px.
The CPU default (``tactus-lite``) trades the first stage's resolution for speed with a
stride-2 3x3 stem (stages at 16, 8, 4, 2 px), chosen by measurement (benchmarks/touch.py).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from importlib import resources
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from tactus_memory.touch.profile import FRAME_SHAPE, MIN_SIDE

#: a stride-2 stem only where the frame's short side is at least this (the configs' stride-2 stem
#: was chosen on the 32x32 glove; a 16x16 skin or a 4x4 pad keeps its full resolution)
STEM_STRIDE_MIN_SIDE = 32
#: a stage halves the map only while its short side is at least this, so the last map keeps
#: 2+ taxels a side (4x4 pad: 4 -> 2 -> 2 -> 2; 32x32 glove: unchanged 16 -> 8 -> 4 -> 2)
STAGE_STRIDE_MIN_SIDE = 4


@dataclass
class TactusConfig:
    name: str = "tactus-r18"  # registry name; also the JSON file stem in configs/
    frames: int = 8  # K, frames per grasp window the fusion layer is trained for (paper: K=8)
    stem_width: int = 64  # channels of the 3x3 stem conv
    stem_stride: int = 1  # 1 keeps the full 32x32 map (paper); 2 halves it (CPU default)
    widths: tuple[int, ...] = (64, 128, 256, 512)  # channels per ResNet stage
    blocks: tuple[int, ...] = (2, 2, 2, 2)  # basic blocks per stage ([2,2,2,2] = ResNet-18)
    proj_hidden: int = 1024  # projector hidden width (paper: 512 -> 1024 -> D)
    out_dim: int = 2048  # D, the frozen text space's dimension (paper: 2048; MiniLM: 384)
    dropout: float = 0.0  # Dropout2d on trunk features before fusion (STAG reference: 0.2)
    # Input shaping, fixed (not learned), applied to every frame before the trunk. On the
    # held-out blindfolded frames a 1-NN over training frames goes from 0.21 to 0.39 with
    # x ** 0.3 and a 1 px blur (benchmarks/results/touch_probe.json), but the CNN trained on
    # shaped input did not gain (touch ladder rung "shaped"). Defaults: off (the paper's recipe).
    input_gamma: float = 1.0  # pressure compression x ** gamma (1.0 = off)
    input_blur: float = 0.0  # Gaussian blur sigma in pixels (0.0 = off)
    # the sensor's (H, W) frame: the stem and stage strides adapt to it (strides())
    frame_shape: tuple[int, int] = FRAME_SHAPE
    # Where the text embedding of each class lives is not the model's business; see targets.py.
    extra: dict[str, Any] = field(default_factory=dict)  # free-form notes carried in metadata

    def __post_init__(self) -> None:
        self.widths = tuple(int(w) for w in self.widths)
        self.blocks = tuple(int(b) for b in self.blocks)
        self.frame_shape = tuple(int(v) for v in self.frame_shape)  # type: ignore[assignment]
        if len(self.frame_shape) != 2 or min(self.frame_shape) < MIN_SIDE:
            raise ValueError(f"frame_shape must be (H, W) with H, W >= {MIN_SIDE}")
        if len(self.widths) != len(self.blocks) or not self.widths:
            raise ValueError(f"widths {self.widths} and blocks {self.blocks} must pair up")
        if self.frames < 1 or self.out_dim < 1:
            raise ValueError("frames and out_dim must be positive")
        if self.stem_stride not in (1, 2):
            raise ValueError(f"stem_stride must be 1 or 2, got {self.stem_stride}")
        if not 0.0 < self.input_gamma <= 1.0 or not 0.0 <= self.input_blur <= 4.0:
            raise ValueError(
                f"input_gamma must be in (0, 1] and input_blur in [0, 4], "
                f"got {self.input_gamma} and {self.input_blur}"
            )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["widths"] = list(self.widths)
        d["blocks"] = list(self.blocks)
        d["frame_shape"] = list(self.frame_shape)
        return d

    def strides(self) -> tuple[int, list[int]]:
        """(stem stride, [stride of each stage]) for ``frame_shape``: the configured stride-2
        stem only on frames whose short side is >= STEM_STRIDE_MIN_SIDE, and a stage halves the
        map only while its short side is >= STAGE_STRIDE_MIN_SIDE (a small frame must not
        vanish under stride-2 convolutions). On 32x32 this is the configs' own layout."""
        side = min(self.frame_shape)
        stem = self.stem_stride if side >= STEM_STRIDE_MIN_SIDE else 1
        side = -(-side // stem)
        stages = []
        for i in range(len(self.widths)):
            s = 2 if i > 0 and side >= STAGE_STRIDE_MIN_SIDE else 1
            stages.append(s)
            side = -(-side // s)
        return stem, stages

    def out_shape(self) -> tuple[int, int]:
        """(h, w) of the trunk's output map for a ``frame_shape`` frame."""
        stem, stages = self.strides()
        h, w = self.frame_shape
        for s in (stem, *stages):
            h, w = -(-h // s), -(-w // s)
        return h, w

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TactusConfig:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 convs with BN, identity or 1x1-projected shortcut."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.short: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.short = nn.Sequential(
                nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return F.relu(y + self.short(x))


class Trunk(nn.Module):
    """Per-frame ResNet. x: (N, 1, H, W) -> (N, widths[-1], h, w), (h, w) = cfg.out_shape()."""

    def __init__(self, cfg: TactusConfig) -> None:
        super().__init__()
        stem_stride, stage_strides = cfg.strides()
        self.stem = nn.Sequential(
            nn.Conv2d(1, cfg.stem_width, 3, stem_stride, 1, bias=False),
            nn.BatchNorm2d(cfg.stem_width),
            nn.ReLU(inplace=True),
        )
        layers: list[nn.Module] = []
        c_in = cfg.stem_width
        for i, (w, n) in enumerate(zip(cfg.widths, cfg.blocks, strict=True)):
            for j in range(n):
                stride = stage_strides[i] if j == 0 else 1
                layers.append(BasicBlock(c_in, w, stride))
                c_in = w
        self.stages = nn.Sequential(*layers)
        self.out_channels = c_in
        # spatial size of the output map (its short side) for a frame_shape input
        self.out_size = min(cfg.out_shape())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.stages(self.stem(x))


def gaussian_kernel(sigma: float) -> torch.Tensor:
    """A normalised (1, 1, n, n) Gaussian kernel, n = 2 * ceil(2 sigma) + 1."""
    r = max(1, int(np.ceil(2 * sigma)))
    g = torch.exp(-(torch.arange(-r, r + 1, dtype=torch.float32) ** 2) / (2 * sigma**2))
    k2 = torch.outer(g, g)
    return (k2 / k2.sum())[None, None]


class InputShaping(nn.Module):
    """x (N, 1, 32, 32) calibrated -> clamp(x, 0) ** gamma, then a fixed Gaussian blur."""

    def __init__(self, gamma: float, blur: float) -> None:
        super().__init__()
        self.gamma = gamma
        # derived from the config, not a weight: kept out of the state dict
        self.register_buffer(
            "kernel", gaussian_kernel(blur) if blur > 0 else torch.ones(1, 1, 1, 1), False
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.gamma != 1.0:
            x = x.clamp(min=0.0) ** self.gamma
        if self.kernel.shape[-1] > 1:
            pad = self.kernel.shape[-1] // 2
            x = F.conv2d(F.pad(x, (pad, pad, pad, pad), mode="replicate"), self.kernel)
        return x


class TactusModel(nn.Module):
    """frames (B, K, 32, 32) float32 calibrated -> (B, D) float32, unit rows."""

    def __init__(self, cfg: TactusConfig) -> None:
        super().__init__()
        self.cfg = cfg
        shaped = cfg.input_gamma != 1.0 or cfg.input_blur > 0
        self.shape_input = (
            InputShaping(cfg.input_gamma, cfg.input_blur) if shaped else nn.Identity()
        )
        self.trunk = Trunk(cfg)
        c = self.trunk.out_channels
        self.drop = nn.Dropout2d(cfg.dropout) if cfg.dropout > 0 else nn.Identity()
        self.fuse = nn.Sequential(
            nn.Conv2d(cfg.frames * c, c, 1, bias=False), nn.BatchNorm2d(c), nn.ReLU(inplace=True)
        )
        self.proj = nn.Sequential(
            nn.Linear(c, cfg.proj_hidden), nn.GELU(), nn.Linear(cfg.proj_hidden, cfg.out_dim)
        )

    def pad_frames(self, frames: torch.Tensor) -> torch.Tensor:
        """(B, k, 32, 32) with k <= K -> (B, K, 32, 32), repeating the last frame."""
        if frames.ndim != 4 or min(frames.shape[-2:]) < MIN_SIDE:
            raise ValueError(
                f"frames must be (B, K, H, W) with H, W >= {MIN_SIDE}, got {tuple(frames.shape)}"
            )
        k, big_k = frames.shape[1], self.cfg.frames
        if k < 1:
            raise ValueError("a window needs at least one frame")
        if k > big_k:
            raise ValueError(
                f"window has {k} frames but {self.cfg.name} fuses K={big_k}; "
                f"pass at most {big_k} frames (e.g. frames[:, :{big_k}])"
            )
        if k < big_k:
            last = frames[:, -1:].expand(-1, big_k - k, -1, -1)
            frames = torch.cat([frames, last], dim=1)
        return frames

    def features(self, frames: torch.Tensor) -> torch.Tensor:
        """(B, K, 32, 32) -> pooled fused features (B, C), before the projector."""
        frames = self.pad_frames(frames)
        b, k = frames.shape[:2]
        x = self.shape_input(frames.reshape(b * k, 1, *frames.shape[-2:]))  # any sensor's H, W
        f = self.drop(self.trunk(x))  # (B*K, C, h, w)
        f = f.reshape(b, k * f.shape[1], f.shape[2], f.shape[3])  # concat frames on channels
        return self.fuse(f).mean(dim=(2, 3))

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.proj(self.features(frames)).float(), dim=-1)


# -- registry ---------------------------------------------------------------------------------


def list_models() -> list[str]:
    """Names of the JSON configs shipped in tactus_memory/touch/configs/."""
    root = resources.files("tactus_memory.touch") / "configs"
    return sorted(p.name[: -len(".json")] for p in root.iterdir() if p.name.endswith(".json"))


def get_config(name: str, out_dim: int | None = None, **overrides: Any) -> TactusConfig:
    """Read configs/<name>.json; ``out_dim`` and keyword overrides replace its fields."""
    path = resources.files("tactus_memory.touch") / "configs" / f"{name}.json"
    if not path.is_file():
        raise ValueError(f"unknown touch model {name!r}; known: {', '.join(list_models())}")
    d = json.loads(path.read_text())
    d["name"] = name
    if out_dim is not None:
        d["out_dim"] = int(out_dim)
    d.update(overrides)
    return TactusConfig.from_dict(d)


def create_model(name: str, out_dim: int | None = None, **overrides: Any) -> TactusModel:
    """``create_model("tactus-r18", 2048)`` -> an untrained TactusModel."""
    return TactusModel(get_config(name, out_dim, **overrides))


def count_params(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def param_report(model: TactusModel) -> dict[str, int]:
    """Trained parameters by part: trunk, fusion, projector, total."""
    return {
        "trunk": count_params(model.trunk),
        "fusion": count_params(model.fuse),
        "projector": count_params(model.proj),
        "total": count_params(model),
    }


if __name__ == "__main__":  # python -m tactus_memory.touch.model
    for n in list_models():
        for d in (384, 2048):
            print(n, d, param_report(create_model(n, d)))


def batched_forward(
    forward: Callable[[torch.Tensor], torch.Tensor],
    windows: np.ndarray,
    batch: int,
    device: str,
    width: int,
) -> np.ndarray:
    """(B, ...) windows -> (B, width) float32: ``forward`` over consecutive slices of
    ``batch`` windows (float32, on ``device``); the caller sets eval and inference mode."""
    outs = []
    for s in range(0, len(windows), batch):
        x = torch.from_numpy(np.ascontiguousarray(windows[s : s + batch], np.float32))
        outs.append(forward(x.to(device)).float().cpu().numpy())
    return np.concatenate(outs) if outs else np.zeros((0, width), np.float32)
