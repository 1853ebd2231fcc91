"""Fine-tune a touch checkpoint on a user's few labelled grasps, on a CPU in seconds.

The shipped encoder (or any checkpoint) keeps its backbone: the per-frame trunk and the frame
fusion are frozen, so the pooled features of every window are computed ONCE (the windows and
:data:`AdaptConfig.copies` - 1 augmented copies of each, the training augmentation), and only
the projector (Linear-GELU-Linear, ~0.3 M parameters of tactus-lite) trains on that cache:

    windows (W, K, H, W') -> frozen trunk + fusion -> features (W * copies, C), cached
    features -> projector (trained) -> normalise -> (., D) in the text space
    loss = cross-entropy of cos(z, centred targets) / TEMPERATURE (training's own loss)
    after each AdamW step: theta <- theta - lr * anchor * (theta - theta_base)

The targets are the base checkpoint's classes plus each new label (its class phrases
embedded by the space, centred on the BASE centroid, so the base classes' targets and the
query transform stay as they were); the base classes are the negatives a new label is told
apart from. ``anchor`` pulls the projector back towards the base's (decoupled L2-SP), so
what was not taught moves little.

The written checkpoint is a normal one (``TactusEncoder(path)``, ``tactus reembed``): its
metadata records the base's sha256, the grasps' source and fingerprint, the config, and the
top-1 of the grasps' own windows before and after. ``<out>.resume.pt`` holds the resume
state (projector, optimiser, generator, step); ``resume=True`` continues from it.
"""

from __future__ import annotations

import copy
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from tactus_memory.errors import InvalidInputError
from tactus_memory.results import label_key
from tactus_memory.touch.checkpoint import (
    Checkpoint,
    load_resume,
    resume_path,
    save_checkpoint,
    save_resume,
)
from tactus_memory.touch.targets import Targets, build_targets, centre, target_report
from tactus_memory.training.adapt_data import Grasps
from tactus_memory.training.augment import AugmentConfig, augment
from tactus_memory.training.train import TEMPERATURE

log = logging.getLogger(__name__)

#: windows per forward pass when the features are cached
FEATURE_BATCH = 256
#: what ``AdaptConfig.tune`` may train
TUNE = ("projector", "fusion")


class FusedHead(torch.nn.Module):
    """Cached trunk maps (B, K*C, h, w) -> the model's fusion, pooling and projector (B, D)
    (``TactusModel.features`` after the trunk)."""

    def __init__(self, fuse: torch.nn.Module, proj: torch.nn.Module) -> None:
        super().__init__()
        self.fuse, self.proj = fuse, proj

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        return self.proj(self.fuse(maps).mean(dim=(2, 3)))

    def train(self, mode: bool = True) -> FusedHead:
        super().train(mode)
        for m in self.fuse.modules():  # few windows: the fusion keeps the base's statistics
            if isinstance(m, torch.nn.BatchNorm2d):
                m.eval()
        return self


def trunk_maps(model: Any, frames: torch.Tensor) -> torch.Tensor:
    """(B, K, H, W) -> (B, K*C, h, w): the trunk's maps of every frame, concatenated on
    channels, as ``TactusModel.features`` feeds them to the fusion."""
    frames = model.pad_frames(frames)
    b, k = frames.shape[:2]
    f = model.trunk(model.shape_input(frames.reshape(b * k, 1, *frames.shape[-2:])))
    return f.reshape(b, k * f.shape[1], f.shape[2], f.shape[3])


@dataclass
class AdaptConfig:
    steps: int = 300  # AdamW steps on the cached features
    lr: float = 1e-3  # AdamW learning rate (constant)
    batch: int = 256  # cached feature rows per step (all of them when fewer)
    copies: int = 8  # feature rows per window: the window and copies - 1 augmented ones
    anchor: float = 0.05  # decoupled pull of the projector towards the base's, per step x lr
    seed: int = 0  # augmentation draws and batches
    save_every: int = 100  # write the resume state every this many steps
    # what trains: "projector" (cache the pooled features) or "fusion" (cache the trunk's
    # per-frame maps; the 1x1 frame fusion, its BatchNorm in eval mode, and the projector)
    tune: str = "projector"
    augment: AugmentConfig = field(default_factory=AugmentConfig)

    def __post_init__(self) -> None:
        for name in ("steps", "batch", "copies", "save_every"):
            if int(getattr(self, name)) < 1:
                raise InvalidInputError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.tune not in TUNE:
            raise InvalidInputError(f"tune must be one of {', '.join(TUNE)}, got {self.tune!r}")
        if self.lr <= 0 or self.anchor < 0:
            raise InvalidInputError(f"lr must be > 0 and anchor >= 0, got {self.lr}, {self.anchor}")


def adapted_targets(base: Targets, space: Any, labels: list[str]) -> Targets:
    """The base's targets plus one per new label (a label equal to a base class, by
    ``label_key``, is that class), all centred on the base's centroid."""
    if space.name != base.space_name or int(space.dim) != base.raw.shape[1]:
        raise InvalidInputError(
            f"the base checkpoint was trained in space {base.space_name!r} "
            f"(dim {base.raw.shape[1]}), not {space.name!r} (dim {space.dim})"
        )
    have = {label_key(c) for c in base.classes}
    new = [x for x in dict.fromkeys(labels) if label_key(x) not in have]
    classes, phrases, raw = list(base.classes), list(base.phrases), base.raw
    if new:
        t = build_targets(space, new)
        classes, phrases = classes + t.classes, phrases + t.phrases
        raw = np.concatenate([raw, t.raw]).astype(np.float32)
    return Targets(
        classes=classes,
        phrases=phrases,
        raw=raw,
        centroid=base.centroid,
        centred=centre(raw, base.centroid),
        space_name=base.space_name,
        space_fingerprint=base.space_fingerprint,
    )


def label_index(targets: Targets, labels: list[str]) -> np.ndarray:
    """(W,) int64 target row of each window's label."""
    row = {label_key(c): i for i, c in enumerate(targets.classes)}
    return np.asarray([row[label_key(x)] for x in labels], np.int64)


@torch.inference_mode()
def cached_features(
    base: Checkpoint, windows: np.ndarray, cfg: AdaptConfig, progress: bool
) -> torch.Tensor:
    """(W, K, H, W') windows -> (copies, W, ...) cached inputs of what trains: pooled
    features (W, C) for ``tune="projector"``, trunk maps (W, K*C, h, w) for ``"fusion"``;
    copy 0 of each window as it is, the others augmented (fixed seed: a resumed run caches
    the same)."""
    model = base.model
    assert model is not None
    model.eval()
    gen = torch.Generator().manual_seed(cfg.seed)
    x = torch.from_numpy(np.ascontiguousarray(windows, np.float32))
    out = []
    bar = tqdm(total=cfg.copies * len(x), desc="features", unit="win", disable=not progress)
    for c in range(cfg.copies):
        rows = []
        for s in range(0, len(x), FEATURE_BATCH):
            chunk = x[s : s + FEATURE_BATCH]
            if c > 0:
                chunk = augment(chunk, cfg.augment, gen)
            cached = model.features(chunk) if cfg.tune == "projector" else trunk_maps(model, chunk)
            rows.append(cached.float())
            bar.update(len(chunk))
        out.append(torch.cat(rows))
    bar.close()
    return torch.stack(out)  # (copies, W, C)


def _top1(head: torch.nn.Module, feats: torch.Tensor, tgt: torch.Tensor, y: torch.Tensor) -> float:
    with torch.inference_mode():
        head.eval()
        z = F.normalize(head(feats).float(), dim=-1)
        return float(((z @ tgt.T).argmax(1) == y).float().mean())


def adapt(
    base: Checkpoint,
    grasps: Grasps,
    space: Any,
    out: str | os.PathLike[str],
    cfg: AdaptConfig | None = None,
    *,
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Fine-tune ``base``'s projector on ``grasps`` and write ``out`` (.safetensors; its
    folder is made). Returns the summary recorded in the checkpoint's ``metrics.adapt``."""
    cfg = cfg or AdaptConfig()
    if base.model is None:
        raise InvalidInputError("adapt needs the base checkpoint's weights (load with torch)")
    model = base.model
    k = int(model.cfg.frames)
    shape = tuple(model.cfg.frame_shape)
    if grasps.windows.ndim != 4 or grasps.windows.shape[1] != k:
        raise InvalidInputError(f"windows must be (W, {k}, H, W), got {grasps.windows.shape}")
    if tuple(grasps.windows.shape[2:]) != shape:
        raise InvalidInputError(
            f"{grasps.source}: frames are {grasps.windows.shape[2:]}, the base checkpoint "
            f"{base.path.name} reads {shape}"
        )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    targets = adapted_targets(base.targets, space, grasps.labels)
    tgt = torch.from_numpy(np.ascontiguousarray(targets.centred, np.float32))
    y_win = torch.from_numpy(label_index(targets, grasps.labels))  # (W,)
    t0 = time.perf_counter()
    feats = cached_features(base, grasps.windows, cfg, progress)  # (copies, W, C)
    feature_s = time.perf_counter() - t0
    flat = feats.reshape(-1, *feats.shape[2:])  # (copies * W, ...)
    y = y_win.repeat(cfg.copies)

    base_head: torch.nn.Module = model.proj
    if cfg.tune == "fusion":
        base_head = FusedHead(model.fuse, model.proj)
    base_head.eval()
    head = copy.deepcopy(base_head).train()
    anchors = [p.detach().clone() for p in base_head.parameters()]
    before = _top1(base_head, feats[0], tgt, y_win)
    opt = torch.optim.AdamW(head.parameters(), lr=cfg.lr, weight_decay=0.0)
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    state = resume_path(out)
    step, history = 0, []
    if resume and state.exists():
        try:
            step, history = load_resume(state, module=head, opt=opt, gen=gen, key="proj")
        except (RuntimeError, KeyError, ValueError) as exc:
            raise InvalidInputError(f"{state} is not the resume state of this adapt run") from exc
        log.info("resumed adapting at step %d", step)
    steps_this_run, t1, loss_v = 0, time.perf_counter(), float("nan")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small matrices: a second thread only spins on a shared CPU
    bar = tqdm(total=cfg.steps, initial=step, desc="adapt", disable=not progress)
    while step < cfg.steps:
        rows = torch.randint(0, len(flat), (min(cfg.batch, len(flat)),), generator=gen)
        z = F.normalize(head(flat[rows]).float(), dim=-1)
        loss = F.cross_entropy((z @ tgt.T) / TEMPERATURE, y[rows])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        with torch.no_grad():  # decoupled L2-SP: back towards the base projector
            for p, p0 in zip(head.parameters(), anchors, strict=True):
                p.sub_(cfg.lr * cfg.anchor * (p - p0))
        step += 1
        steps_this_run += 1
        loss_v = float(loss.detach())
        if step % 25 == 0 or step == cfg.steps:
            history.append({"step": step, "loss": loss_v})
        bar.set_postfix(loss=f"{loss_v:.3f}")
        bar.update(1)
        if step % cfg.save_every == 0 or step == cfg.steps:
            save_resume(
                state, module=head, opt=opt, gen=gen, step=step, history=history, key="proj"
            )
    bar.close()
    torch.set_num_threads(threads)
    head.eval()
    after = _top1(head, feats[0], tgt, y_win)
    adapted = copy.deepcopy(model)
    if isinstance(head, FusedHead):
        adapted.fuse.load_state_dict(head.fuse.state_dict())
        adapted.proj.load_state_dict(head.proj.state_dict())
    else:
        adapted.proj.load_state_dict(head.state_dict())
    summary: dict[str, Any] = {
        "base": {"file": base.path.name, "sha256": base.sha256},
        "grasps": grasps.summary(),
        "new_labels": targets.classes[len(base.targets.classes) :],
        "steps": step,
        "steps_this_run": steps_this_run,
        "feature_s": round(feature_s, 2),
        "train_s": round(time.perf_counter() - t1, 2),
        "loss_last": loss_v,
        "own_windows_top1": {"before": before, "after": after},
        "trained": ["projector"] if cfg.tune == "projector" else ["fuse", "projector"],
        "frozen": ["trunk", "fuse"] if cfg.tune == "projector" else ["trunk"],
        "threads": threads,  # of the features; the steps run on one
    }
    train_args = {"adapt": {**asdict(cfg), "base_sha256": base.sha256}}
    save_checkpoint(
        out,
        adapted,
        targets,
        space_dim=int(base.dim),
        calibration=base.meta.get("calibration", {}),
        fingerprint=grasps.fingerprint(),
        seed=cfg.seed,
        steps=int(base.meta.get("steps", 0)),
        metrics={"adapt": summary, "base_metrics": base.meta.get("metrics", {})},
        train_args=train_args,
        target_geometry=target_report(targets),
    )
    return summary
