"""Distillation: a fast student learns one or more teachers' embeddings plus the labels.

The student is trained by :func:`tactus_memory.training.train.fit` (same tuples, same
augmentation, same schedule, same resume state) with one extra loss term on every step:

    t      = normalize(mean over teachers of the teachers' unit embeddings of the SAME
             augmented batch x)                                        (B, D)
    loss   = CE(cos(z, targets_centred) / 0.07, y)                     the training loss
           + cosine_weight     * mean(1 - cos(z, t))                   embedding match
           + relational_weight * mean((z z^T - t t^T)^2)               similarity structure

Teachers must live where the student's targets live: the same space (name, dim, model
fingerprint) and the same sensor calibration, else :class:`TeacherMismatchError` names the
difference. Their files' sha256 go into the student's ``train_args["distill"]``, so the
checkpoint says what taught it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from tactus_memory.touch.checkpoint import Checkpoint, load_checkpoint
from tactus_memory.touch.targets import Targets
from tactus_memory.training.precision import autocast
from tactus_memory.training.train import TrainConfig, TrainData, _resolve_device, fit

log = logging.getLogger(__name__)


class TeacherMismatchError(ValueError):
    """A teacher checkpoint cannot teach this student (another space, dim or calibration)."""


@dataclass(frozen=True)
class DistillConfig:
    """The teacher loss's weights (added to the label cross-entropy)."""

    cosine_weight: float = 1.0  # weight of mean(1 - cos(student, teacher mean))
    relational_weight: float = 0.0  # weight of the batch similarity-matrix MSE

    def __post_init__(self) -> None:
        for name in ("cosine_weight", "relational_weight"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.cosine_weight == 0 and self.relational_weight == 0:
            raise ValueError("cosine_weight and relational_weight are both 0: nothing to distil")


def check_teacher(
    teacher: Checkpoint, targets: Targets, space_dim: int, calibration: dict[str, Any], k: int
) -> None:
    """Raise TeacherMismatchError unless ``teacher`` embeds into the student's space (name,
    dim, fingerprint), with the data's calibration, and fuses at least ``k`` frames."""
    name = teacher.path.name
    have = teacher.meta["space"]
    want_fp = targets.space_fingerprint
    if have["name"] != targets.space_name or int(have["dim"]) != int(space_dim):
        raise TeacherMismatchError(
            f"teacher {name} embeds into space {have['name']!r} (dim {have['dim']}), the student "
            f"into {targets.space_name!r} (dim {space_dim}): distil within one space (--space)"
        )
    if have.get("fingerprint") and want_fp and have["fingerprint"] != want_fp:
        raise TeacherMismatchError(
            f"teacher {name} was trained in {have['name']!r} fingerprinted {have['fingerprint']}, "
            f"the student's space is fingerprinted {want_fp}: not the same model"
        )
    if teacher.meta.get("calibration") and teacher.meta["calibration"] != calibration:
        raise TeacherMismatchError(
            f"teacher {name} was trained on another sensor calibration "
            f"({teacher.meta['calibration'].get('name')!r}) than this data's "
            f"({calibration.get('name')!r})"
        )
    if teacher.model.cfg.frames < k:
        raise TeacherMismatchError(
            f"teacher {name} fuses K={teacher.model.cfg.frames} frames, the student {k}"
        )


class TeacherLoss:
    """The extra loss :func:`fit` adds: cosine and relational terms against the teachers'
    mean embedding of the student's own augmented batch."""

    def __init__(self, teachers: Sequence[Checkpoint], cfg: DistillConfig) -> None:
        self.models = [t.model.eval() for t in teachers]
        self.cfg = cfg

    @torch.no_grad()
    def teach(self, x: torch.Tensor) -> torch.Tensor:
        """x: (B, K, 32, 32) -> (B, D) unit mean of the teachers' unit embeddings."""
        # on CUDA the teachers run under bf16 autocast like the student (their outputs are
        # normalised in float32 below); on CPU in float32
        with autocast(x.device):
            zs = [m(x).float() for m in self.models]
        return F.normalize(torch.stack(zs).mean(dim=0), dim=-1)

    def __call__(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        t = self.teach(x)
        loss = z.new_zeros(())
        if self.cfg.cosine_weight:
            loss = loss + self.cfg.cosine_weight * (1.0 - (z * t).sum(dim=-1)).mean()
        if self.cfg.relational_weight:
            rel = F.mse_loss(z @ z.T, t @ t.T)
            loss = loss + self.cfg.relational_weight * rel
        return loss


def teacher_record(teacher: Checkpoint) -> dict[str, Any]:
    """What the student's train_args keep about one teacher."""
    held = (teacher.meta.get("metrics") or {}).get("heldout") or {}
    return {
        "file": teacher.path.name,
        "sha256": teacher.sha256,
        "model": teacher.model.cfg.name,
        "heldout_top1": held.get("top1"),
        "heldout_recording_top1": held.get("recording_top1"),
    }


def distill(
    data: TrainData,
    targets: Targets,
    cfg: TrainConfig,
    out: str | os.PathLike[str],
    teachers: Sequence[str | os.PathLike[str]],
    *,
    space_dim: int,
    dcfg: DistillConfig | None = None,
    pretrained: str | os.PathLike[str] | None = None,
    device: str = "auto",
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the ``cfg.model`` student on ``data`` with the teachers' loss (see the module
    docstring) and save ``out``; returns fit's summary plus the teachers."""
    if not teachers:
        raise ValueError("distillation needs at least one --teacher checkpoint")
    dcfg = dcfg or DistillConfig()
    device = _resolve_device(device)
    loaded = [load_checkpoint(p, device=device) for p in teachers]
    for t in loaded:
        check_teacher(t, targets, space_dim, data.calibration, cfg.k)
        named = ((t.meta.get("metrics") or {}).get("heldout") or {}).get("recordings_named")
        if data.heldout_recordings and set(data.heldout_recordings) - set(named or []):
            log.warning(
                "teacher %s did not hold out every recording the student is scored on: "
                "the student's validation is optimistic",
                t.path.name,
            )
    record = {
        "distill": {
            "teachers": [teacher_record(t) for t in loaded],
            "cosine_weight": dcfg.cosine_weight,
            "relational_weight": dcfg.relational_weight,
        }
    }
    summary = fit(
        data,
        targets,
        cfg,
        out,
        space_dim=space_dim,
        pretrained=pretrained,
        device=device,
        resume=resume,
        progress=progress,
        extra_loss=TeacherLoss(loaded, dcfg),
        extra_args=record,
    )
    summary.update(record)
    return summary
