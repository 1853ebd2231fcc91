"""The supervised STAG classifier (closed-set baseline), re-implemented from stag-format.md.

Architecture ("Reference classifier"), per frame a shared trunk::

    frame (1, 32, 32)
      -> 3x3 conv s1 -> 64, BN, ReLU                       (64, 32, 32)
      -> 3x3 max-pool s2 (padding 1)                        (64, 16, 16)
      -> 2 ResNet basic blocks at 64                        (64, 16, 16)
      -> Dropout2d(0.2)
      -> 2 basic blocks at 128, the first with stride 2     (128, 8, 8)

then the N frames of a tuple are fused: channel concat (N*128, 8, 8) -> 1x1 conv to 128
(+ BN + ReLU: the spec names only the conv; we normalise it like every other conv here)
-> global average pool (128) -> Linear to 27 logits.

Training: cross-entropy, Adam lr 1e-3, batch 32, ``epochs`` passes (30 by default) over the
training tuples (one cluster tuple per anchor, redrawn every epoch, as in the reference),
Gaussian noise std 0.015 added to the calibrated frames (training only). The model of the
LAST epoch is saved: unlike the reference code, nothing is selected on the test split (or on
the held-out recordings).

Scoring goes through the same evaluation as Tactus (``evaluate.evaluate_scorer``): the
"embedding" of a window is its class-probability vector, votes and recording windows are
pooled by averaging probabilities, and ranking is by probability.

Checkpoint: safetensors, tensors ``model.*``, metadata key ``tactus_baseline`` (JSON: format,
classes, K, config, calibration, data fingerprint, holdout, held-out metrics, licence) and a
``.json`` sidecar with the same metadata.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm.auto import tqdm

from tactus_memory import __version__
from tactus_memory.touch.model import BasicBlock, batched_forward
from tactus_memory.touch.profile import FRAME_SHAPE

if TYPE_CHECKING:
    from tactus_memory.training.train import TrainData

BASELINE_META_KEY = "tactus_baseline"
FORMAT = "tactus-stag-baseline/1"
NOISE_STD = 0.015  # stag-format.md: Gaussian noise std 0.015 after calibration, train only
LICENSE_NOTE = (
    "Trained on STAG (non-commercial research use only); weights inherit CC-BY-NC-4.0 terms."
)


class StagTrunk(nn.Module):
    """Per-frame trunk of the reference classifier. (B, 1, 32, 32) -> (B, 128, 8, 8)."""

    def __init__(self, dropout: float = 0.2) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(1, 64, 3, 1, 1, bias=False),
            nn.BatchNorm2d(64),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        self.layer1 = nn.Sequential(BasicBlock(64, 64, 1), BasicBlock(64, 64, 1))
        self.drop = nn.Dropout2d(dropout)
        self.layer2 = nn.Sequential(BasicBlock(64, 128, 2), BasicBlock(128, 128, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layer2(self.drop(self.layer1(self.stem(x))))


class StagCNN(nn.Module):
    """frames (B, N, 32, 32) calibrated -> (B, n_classes) logits."""

    def __init__(self, n_classes: int = 27, frames: int = 8, dropout: float = 0.2) -> None:
        super().__init__()
        self.frames, self.n_classes, self.dropout = int(frames), int(n_classes), float(dropout)
        self.trunk = StagTrunk(dropout)
        self.fuse = nn.Sequential(
            nn.Conv2d(frames * 128, 128, 1, bias=False), nn.BatchNorm2d(128), nn.ReLU(inplace=True)
        )
        self.fc = nn.Linear(128, n_classes)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if frames.ndim != 4 or tuple(frames.shape[1:]) != (self.frames, *FRAME_SHAPE):
            raise ValueError(
                f"frames must be (B, {self.frames}, 32, 32), got {tuple(frames.shape)}"
            )
        b, n = frames.shape[:2]
        f = self.trunk(frames.reshape(b * n, 1, *FRAME_SHAPE))  # (B*N, 128, 8, 8)
        f = f.reshape(b, n * 128, f.shape[2], f.shape[3])  # channel concat of the N frames
        return self.fc(self.fuse(f).mean(dim=(2, 3)))


@dataclass
class BaselineConfig:
    epochs: int = 30  # passes over the training tuples (reference: 30)
    batch: int = 32  # reference: 32
    lr: float = 1e-3  # Adam, reference: 1e-3
    noise: float = NOISE_STD
    k: int = 8  # frames per tuple
    sampling: str = "cluster"
    dropout: float = 0.2
    seed: int = 0
    max_steps: int | None = None  # optional cap on optimizer steps (quick runs, tests)


@torch.inference_mode()
def predict_proba(
    net: StagCNN, windows: np.ndarray, batch: int = 128, device: str = "cpu"
) -> np.ndarray:
    """(B, N, 32, 32) calibrated -> (B, C) float32 softmax probabilities (eval mode)."""
    net.eval()

    def probs(x: torch.Tensor) -> torch.Tensor:
        return F.softmax(net(x).float(), dim=-1)

    return batched_forward(probs, windows, batch, device, net.n_classes)


@dataclass
class BaselineScorer:
    """The baseline behind the evaluation's Scorer protocol (probabilities as embeddings)."""

    net: StagCNN
    classes: list[str]
    device: str = "cpu"
    kind: str = "baseline"

    @property
    def k(self) -> int:
        return self.net.frames

    def embed(self, windows: np.ndarray) -> np.ndarray:
        return predict_proba(self.net, windows, device=self.device)

    def pool(self, embs: np.ndarray) -> np.ndarray:
        return np.asarray(embs, dtype=np.float32).mean(axis=0)

    def scores(self, emb: np.ndarray) -> np.ndarray:
        return np.asarray(emb, dtype=np.float32)


def train_baseline(
    data: TrainData,
    cfg: BaselineConfig,
    *,
    device: str = "cpu",
    progress: bool = True,
    on_epoch: Callable[[StagCNN, dict[str, Any]], None] | None = None,
) -> tuple[StagCNN, dict[str, Any]]:
    """Train on ``data.train_valid`` (anchors ``data.train_anchors``); returns (model, summary).

    No validation, no early stopping, no model selection: the last epoch's weights.
    ``on_epoch(net, summary_so_far)`` runs after every epoch (e.g. to write a snapshot that
    survives an interrupted run; it is always the latest epoch, never a selected one).
    """
    torch.manual_seed(cfg.seed)
    net = StagCNN(len(data.classes), cfg.k, cfg.dropout).to(device)
    sampler = data.train_sampler(cfg.k, cfg.sampling, cfg.seed)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    frames = torch.from_numpy(np.ascontiguousarray(data.calibrated, np.float32))
    labels = torch.from_numpy(np.asarray(data.labels, np.int64))
    gen = torch.Generator().manual_seed(cfg.seed)
    per_epoch = -(-len(sampler) // cfg.batch)
    total = per_epoch * cfg.epochs
    if cfg.max_steps is not None:
        total = min(total, int(cfg.max_steps))
    bar = tqdm(total=total, desc="baseline", disable=not progress)
    step, history, t0 = 0, [], time.perf_counter()
    net.train()
    for epoch in range(cfg.epochs):
        if step >= total:
            break
        tuples = torch.from_numpy(sampler.sample(np.random.default_rng([cfg.seed, epoch])))
        order = torch.randperm(len(tuples), generator=gen)
        loss_sum, correct, seen = 0.0, 0, 0
        for s in range(0, len(order), cfg.batch):
            if step >= total:
                break
            idx = tuples[order[s : s + cfg.batch]]  # (B, K)
            x = frames[idx]
            if cfg.noise > 0:
                x = x + cfg.noise * torch.randn(x.shape, generator=gen)
            y = labels[idx[:, 0]]
            logits = net(x.to(device))
            loss = F.cross_entropy(logits, y.to(device))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            loss_sum += float(loss.detach()) * len(y)
            correct += int((logits.argmax(1).cpu() == y).sum())
            seen += len(y)
            bar.set_postfix(epoch=epoch, loss=f"{loss_sum / seen:.3f}", acc=f"{correct / seen:.2f}")
            bar.update(1)
        history.append(
            {
                "epoch": epoch,
                "step": step,
                "loss": loss_sum / max(seen, 1),
                "acc": correct / max(seen, 1),
            }
        )
        if on_epoch is not None:
            net.eval()
            on_epoch(net, _summary(step, history, len(sampler), t0, net))
            net.train()
    bar.close()
    net.eval()
    return net, _summary(step, history, len(sampler), t0, net)


def _summary(
    step: int, history: list[dict[str, Any]], n_tuples: int, t0: float, net: StagCNN
) -> dict[str, Any]:
    return {
        "steps": step,
        "epochs_run": len(history),
        "train_tuples_per_epoch": n_tuples,
        "wall_s": round(time.perf_counter() - t0, 1),
        "params": sum(p.numel() for p in net.parameters()),
        "history": list(history),
        "selection": "last epoch (no model selection on test or held-out data)",
    }


def save_baseline(path: str | os.PathLike[str], net: StagCNN, meta: dict[str, Any]) -> str:
    """Weights + metadata (safetensors, atomically) and a JSON sidecar; returns the sha256."""
    from safetensors.torch import save_file

    from tactus_memory.hashing import file_sha256

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    full = {
        "format": FORMAT,
        "frames": net.frames,
        "n_classes": net.n_classes,
        "dropout": net.dropout,
        "code_version": __version__,
        "license": LICENSE_NOTE,
        **meta,
    }
    tensors = {f"model.{k}": v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    save_file(tensors, str(tmp), metadata={BASELINE_META_KEY: json.dumps(full, sort_keys=True)})
    os.replace(tmp, path)
    sha = file_sha256(path)
    path.with_suffix(".json").write_text(json.dumps(dict(full, sha256=sha), indent=2) + "\n")
    return sha


def load_baseline(path: str | os.PathLike[str], device: str = "cpu") -> tuple[StagCNN, dict]:
    from safetensors import safe_open
    from safetensors.torch import load_file

    with safe_open(str(path), framework="pt") as f:
        md = f.metadata() or {}
    if BASELINE_META_KEY not in md:
        raise ValueError(f"{path} is not a STAG baseline checkpoint")
    meta = json.loads(md[BASELINE_META_KEY])
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: unsupported baseline format {meta.get('format')!r}")
    net = StagCNN(int(meta["n_classes"]), int(meta["frames"]), float(meta.get("dropout", 0.2)))
    state = {k[len("model.") :]: v for k, v in load_file(str(path)).items()}
    net.load_state_dict(state, strict=True)
    net.to(device).eval()
    return net, meta


def baseline_meta(
    data: TrainData, cfg: BaselineConfig, summary: dict[str, Any], holdout: str
) -> dict[str, Any]:
    return {
        "classes": list(data.classes),
        "config": asdict(cfg),
        "epochs": cfg.epochs,
        "seed": cfg.seed,
        "holdout": holdout,
        "heldout_recordings": list(data.heldout_recordings),
        "calibration": data.calibration,
        "data_fingerprint": data.fingerprint,
        "train": {k: v for k, v in summary.items() if k != "history"},
    }
