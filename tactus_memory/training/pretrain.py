"""Masked-autoencoder pretraining of the per-frame trunk on unlabeled same-sensor frames.

Recipe (paper, Pretraining): mask ratio 0.6 over the patches of each frame, per-patch
normalised targets, loss on masked patches only, all same-sensor frames including those
without a valid label, held-out/test recordings excluded.

A conv trunk cannot drop tokens the way a ViT-MAE does, so masked 4x4 patches are zeroed in
the input (calibrated rest is ~0.07, so zero is distinguishable from "no contact") and a
light decoder (1x1 -> upsample to the 8x8 patch grid -> one 3x3 conv -> 16 pixels per
patch) reconstructs them from the trunk's final feature map.

Per-patch normalisation: target = (p - mean(p)) / max(std(p), MIN_PATCH_STD). A flat patch
gives an all-zero target (no NaN); a near-flat patch at rest, whose std is one or two raw
counts of quantisation noise, is not blown up to unit variance, because the std is floored.
Predicting zero (= each patch's mean) costs ``baseline`` = mean squared normalised target,
which is 1.0 without the floor (the paper's "pinned at 1.0" collapse level) and a little less
with it. The loop logs loss / baseline and warns when it stays near 1 after warmup: the
signature of a mean-predicting, collapsed encoder.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from safetensors import safe_open
from safetensors.torch import load_file, save_file
from torch import nn
from tqdm.auto import tqdm

from tactus_memory import __version__
from tactus_memory.touch.checkpoint import load_resume, resume_path, save_resume
from tactus_memory.touch.model import TactusConfig, Trunk, get_config
from tactus_memory.touch.profile import FRAME_SHAPE
from tactus_memory.training.precision import autocast

log = logging.getLogger(__name__)

MASK_RATIO = 0.6  # paper, Pretraining (HTT setting for taxel sensors)
PATCH = 4  # 4x4 patches: a 32x32 frame is an 8x8 grid of 64 patches
GRID = FRAME_SHAPE[0] // PATCH
N_PATCHES = GRID * GRID
MIN_PATCH_STD = 0.02  # calibrated units (= 3 raw counts at 150 counts/unit): std floor
COLLAPSE_RATIO = 0.95  # warn when loss / mean-prediction baseline stays above this
FORMAT = "tactus-mae/1"


def patch_grid(shape: tuple[int, ...]) -> tuple[int, int]:
    """(gh, gw): the patch grid of an (H, W) frame, sides rounded up to whole patches."""
    h, w = shape[-2:]
    return -(-h // PATCH), -(-w // PATCH)


def pad_to_patches(x: torch.Tensor) -> torch.Tensor:
    """(N, H, W) -> (N, gh*PATCH, gw*PATCH), zero-padded right and bottom (0 = no pressure)."""
    gh, gw = patch_grid(tuple(x.shape))
    return F.pad(x, (0, gw * PATCH - x.shape[-1], 0, gh * PATCH - x.shape[-2]))


def patchify(x: torch.Tensor) -> torch.Tensor:
    """(N, H, W), sides multiples of PATCH -> (N, gh*gw, 16): row-major grid of 4x4 patches
    (32x32: (N, 64, 16))."""
    n = x.shape[0]
    gh, gw = patch_grid(tuple(x.shape))
    p = x.reshape(n, gh, PATCH, gw, PATCH).permute(0, 1, 3, 2, 4)
    return p.reshape(n, gh * gw, PATCH * PATCH)


def unpatchify(p: torch.Tensor, grid: tuple[int, int] = (GRID, GRID)) -> torch.Tensor:
    """(N, gh*gw, 16) -> (N, gh*PATCH, gw*PATCH); inverse of ``patchify``."""
    n = p.shape[0]
    gh, gw = grid
    x = p.reshape(n, gh, gw, PATCH, PATCH).permute(0, 1, 3, 2, 4)
    return x.reshape(n, gh * PATCH, gw * PATCH)


def patch_targets(x: torch.Tensor, min_std: float = MIN_PATCH_STD) -> torch.Tensor:
    """(N, H, W) -> (N, P, 16) per-patch normalised: (p - mean) / max(std, min_std)."""
    p = patchify(x.float())
    mean = p.mean(dim=-1, keepdim=True)
    std = p.std(dim=-1, unbiased=False, keepdim=True)
    return (p - mean) / std.clamp(min=min_std)


def random_mask(
    n: int, gen: torch.Generator, ratio: float = MASK_RATIO, n_patches: int = N_PATCHES
) -> torch.Tensor:
    """(N, P) bool, True = masked; exactly round(ratio * P) patches per frame."""
    n_mask = int(round(ratio * n_patches))
    order = torch.argsort(torch.rand(n, n_patches, generator=gen), dim=1)
    mask = torch.zeros(n, n_patches, dtype=torch.bool)
    mask.scatter_(1, order[:, :n_mask], True)
    return mask


def apply_mask(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Zero the masked patches. x: (N, H, W), mask: (N, P) -> (N, H, W)."""
    p = patchify(x) * (~mask).unsqueeze(-1).to(x.dtype)
    return unpatchify(p, patch_grid(tuple(x.shape)))


def masked_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over masked patches only. pred/target: (N, P, 16), mask: (N, P)."""
    per_patch = ((pred.float() - target) ** 2).mean(dim=-1)
    m = mask.float()
    return (per_patch * m).sum() / m.sum().clamp(min=1.0)


class MAEDecoder(nn.Module):
    """Trunk map (N, C, h, w) -> patch predictions (N, gh*gw, 16)."""

    def __init__(self, c_in: int, width: int = 64) -> None:
        super().__init__()
        self.inp = nn.Conv2d(c_in, width, 1)
        self.body = nn.Sequential(
            nn.GELU(),
            nn.Conv2d(width, width, 3, 1, 1),
            nn.GELU(),
            nn.Conv2d(width, PATCH * PATCH, 1),
        )

    def forward(self, f: torch.Tensor, grid: tuple[int, int] = (GRID, GRID)) -> torch.Tensor:
        y = F.interpolate(self.inp(f), size=grid, mode="nearest")
        y = self.body(y)  # (N, 16, gh, gw)
        return y.flatten(2).transpose(1, 2)  # (N, gh*gw, 16)


class MAE(nn.Module):
    """The trunk that ``tactus train --pretrained`` reuses, plus a throwaway decoder."""

    def __init__(self, cfg: TactusConfig, decoder_width: int = 64) -> None:
        super().__init__()
        self.cfg = cfg
        self.trunk = Trunk(cfg)
        self.decoder = MAEDecoder(self.trunk.out_channels, decoder_width)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (N, H, W) calibrated, mask (N, P) over its patch grid (frames padded to whole
        patches) -> (loss, mean-prediction baseline)."""
        x = pad_to_patches(x)
        target = patch_targets(x)
        feats = self.trunk(apply_mask(x, mask).unsqueeze(1))
        pred = self.decoder(feats, patch_grid(tuple(x.shape)))
        baseline = masked_loss(torch.zeros_like(target), target, mask)
        return masked_loss(pred, target, mask), baseline


@dataclass
class PretrainConfig:
    model: str = "tactus-lite"  # trunk architecture (a name in configs/)
    steps: int = 400  # optimizer steps (shipped recipe; loss/baseline plateaus ~0.30)
    batch: int = 128  # frames per step
    lr: float = 1.5e-3  # AdamW peak learning rate
    weight_decay: float = 0.05  # AdamW weight decay
    warmup: int = 150  # linear warmup steps, then cosine to 0
    seed: int = 0  # masks, batch order, init
    save_every: int = 500  # write the resume state every this many steps


def recipe_warmup(steps: int) -> int:
    """Warm-up steps of a run of ``steps``: 5% of the run, at least 1, at most 150 (the shipped
    recipe's rule, for pretraining and training alike)."""
    return max(1, min(150, steps // 20))


def lr_at(step: int, total: int, warmup: int, peak: float) -> float:
    """Linear warmup to ``peak`` then cosine decay to 0 (step is 0-based)."""
    if step < warmup:
        return peak * (step + 1) / warmup
    t = (step - warmup) / max(1, total - warmup)
    return peak * 0.5 * (1.0 + math.cos(math.pi * min(1.0, t)))


def pretrain_pool(recording_id: np.ndarray, exclude_recordings: Iterable[int]) -> np.ndarray:
    """Indices of frames usable for pretraining: every frame whose recording is not excluded."""
    excl = np.fromiter((int(r) for r in exclude_recordings), dtype=np.int64)
    return np.flatnonzero(~np.isin(np.asarray(recording_id, dtype=np.int64), excl))


def pretrain(
    calibrated: np.ndarray,
    recording_id: np.ndarray,
    exclude_recordings: Iterable[int],
    out: str | os.PathLike[str],
    cfg: PretrainConfig,
    *,
    fingerprint: str = "",
    device: str = "cpu",
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """MAE-pretrain a trunk on ``calibrated`` (N, H, W) float32 frames, minus the excluded
    recordings, and save it to ``out`` (.safetensors). Returns a summary dict."""
    exclude = sorted({int(r) for r in exclude_recordings})
    pool = pretrain_pool(recording_id, exclude)
    if len(pool) == 0:
        raise ValueError("no frames left for pretraining after exclusions")
    frames = torch.from_numpy(np.ascontiguousarray(calibrated[pool], dtype=np.float32))
    torch.manual_seed(cfg.seed)
    shape = tuple(int(v) for v in calibrated.shape[-2:])  # the sensor's (H, W)
    gh, gw = patch_grid(shape)
    mae = MAE(get_config(cfg.model, frame_shape=shape)).to(device)
    opt = torch.optim.AdamW(mae.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    gen = torch.Generator().manual_seed(cfg.seed)
    out = Path(out)
    state_path = resume_path(out)
    step, history = 0, []
    if resume and state_path.exists():
        step, history = load_resume(
            state_path, module=mae, opt=opt, gen=gen, device=device, key="mae"
        )
        log.info("resumed MAE pretraining at step %d", step)
    amp = autocast(device)
    mae.train()
    t0, ema, ema_base = time.perf_counter(), None, None
    bar = tqdm(total=cfg.steps, initial=step, desc="mae", disable=not progress)
    warned = False
    while step < cfg.steps:
        for g in opt.param_groups:
            g["lr"] = lr_at(step, cfg.steps, cfg.warmup, cfg.lr)
        idx = torch.randint(0, len(frames), (cfg.batch,), generator=gen)
        x = frames[idx].to(device)
        mask = random_mask(cfg.batch, gen, n_patches=gh * gw).to(device)
        with amp:  # bf16 autocast on CUDA (the losses are computed in float32)
            loss, base = mae(x, mask)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        lv, bv = float(loss.detach()), float(base)
        ema = lv if ema is None else 0.98 * ema + 0.02 * lv
        ema_base = bv if ema_base is None else 0.98 * ema_base + 0.02 * bv
        ratio = ema / max(ema_base, 1e-8)
        if step % 25 == 0 or step == cfg.steps:
            history.append({"step": step, "loss": ema, "baseline": ema_base, "ratio": ratio})
        if not warned and step >= max(2 * cfg.warmup, 100) and ratio > COLLAPSE_RATIO:
            log.warning(
                "MAE loss %.3f is %.0f%% of the mean-prediction level %.3f at step %d: the "
                "encoder may be predicting patch means (collapse); check calibration and lr",
                ema,
                100 * ratio,
                ema_base,
                step,
            )
            warned = True
        bar.set_postfix(loss=f"{ema:.3f}", ratio=f"{ratio:.2f}")
        bar.update(1)
        if step % cfg.save_every == 0 or step == cfg.steps:
            save_resume(
                state_path, module=mae, opt=opt, gen=gen, step=step, history=history, key="mae"
            )
    bar.close()
    wall = time.perf_counter() - t0
    summary = {
        "format": FORMAT,
        "model": mae.cfg.to_dict(),
        "pretrain": asdict(cfg),
        "frames": int(len(pool)),
        "excluded_recordings": exclude,
        "data_fingerprint": fingerprint,
        "final_loss": ema,
        "final_baseline": ema_base,
        "final_ratio": ratio,
        "collapse_warning": warned,
        "wall_s_this_run": wall,
        "code_version": __version__,
        "history": history,
    }
    save_mae(out, mae, summary)
    return summary


def save_mae(path: str | os.PathLike[str], mae: MAE, summary: dict[str, Any]) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().cpu().contiguous() for k, v in mae.state_dict().items()}
    meta = {k: v for k, v in summary.items() if k != "history"}
    save_file(tensors, str(path), metadata={"tactus_mae": json.dumps(meta, sort_keys=True)})
    path.with_suffix(".json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")


def load_pretrained_trunk(trunk: Trunk, path: str | os.PathLike[str], cfg: TactusConfig) -> dict:
    """Copy an MAE checkpoint's trunk weights into ``trunk``; checks the architectures match."""
    with safe_open(str(path), framework="pt") as f:
        md = f.metadata() or {}
    if "tactus_mae" not in md:
        raise ValueError(f"{path} is not a Tactus MAE checkpoint")
    meta = json.loads(md["tactus_mae"])
    src = TactusConfig.from_dict(meta["model"])
    keys = ("stem_width", "stem_stride", "widths", "blocks", "frame_shape")
    if any(getattr(src, k) != getattr(cfg, k) for k in keys):
        raise ValueError(
            f"MAE trunk {src.name} ({[getattr(src, k) for k in keys]}) does not match model "
            f"{cfg.name} ({[getattr(cfg, k) for k in keys]})"
        )
    state = load_file(str(path))
    trunk_state = {k[len("trunk.") :]: v for k, v in state.items() if k.startswith("trunk.")}
    trunk.load_state_dict(trunk_state, strict=True)
    return meta
