"""Supervised training of the touch encoder against centred class-phrase targets.

Recipe (paper, Method): calibrated frames (STAG_GLOVE profile, dynamic-range gate),
cluster-sampled K=8 tuples of valid frames redrawn every RESAMPLE_EVERY steps,
logits = cos(z, targets_centred) / TEMPERATURE, cross-entropy, AdamW with linear warmup and
a cosine schedule, spatial + temporal augmentation (augment.py), optional MAE-initialised
trunk (pretrain.py).

Validation: ``holdout`` recordings are removed from training (and, by the caller, from
pretraining); they are scored on fixed-seed cluster tuples (top-1 / top-3) and per recording
(embeddings of up to 64 valid frames, tiled into K-frame windows, averaged).

CUDA: bf16 autocast and torchrun DDP (``WORLD_SIZE`` > 1) code paths are present and guarded,
but they were only exercised on CPU in this repository (no GPU was available).
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from tactus_memory.touch.checkpoint import load_resume, resume_path, save_checkpoint, save_resume
from tactus_memory.touch.model import TactusModel, batched_forward, create_model, param_report
from tactus_memory.touch.targets import Targets, target_report
from tactus_memory.training.augment import AugmentConfig, augment
from tactus_memory.training.metrics import RECORDING_POOL, recording_windows, topk_accuracy
from tactus_memory.training.precision import autocast
from tactus_memory.training.pretrain import load_pretrained_trunk, lr_at
from tactus_memory.training.tuples import RESAMPLE_EVERY, TupleSampler, consecutive_windows

log = logging.getLogger(__name__)

TEMPERATURE = 0.07  # paper, Method: cross-entropy over cosine logits at temperature 0.07
EVAL_SEED = 1234  # fixed seed of the held-out tuple tiling

#: a loss term added to the label cross-entropy: (x (B, K, H, W) augmented batch on the
#: device, z (B, D) float32 student embeddings) -> scalar tensor (distill.py's teacher loss)
ExtraLoss = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class TrainConfig:
    model: str = "tactus-lite"  # architecture name in configs/
    steps: int = 600  # optimizer steps (shipped recipe; training acc saturates by ~200)
    batch: int = 64  # windows per step (per process under DDP)
    lr: float = 1e-3  # AdamW peak learning rate
    weight_decay: float = 0.05  # AdamW weight decay
    warmup: int = 150  # linear warmup steps, then cosine decay to 0
    seed: int = 0  # init, tuples, batches, augmentation
    k: int = 8  # frames per tuple (paper: K=8)
    sampling: str = "cluster"  # "cluster" (paper) or "random" tuple companions
    resample_every: int = RESAMPLE_EVERY  # redraw training tuples every this many steps
    save_every: int = 250  # write the resume state every this many steps
    # which training windows a batch draws: "none" = uniform over tuples (the paper), "recording"
    # = every recording equally often, "class" = every class equally often (the weights_lite
    # file has ~17x more labelled frames per recording than the blindfolded one)
    balance: str = "none"
    consecutive: float = 0.0  # share of training windows cut as K consecutive frames (stream-like)
    # TactusConfig fields set on the model, e.g. {"input_gamma": 0.3, "input_blur": 1.0};
    # they end up in the checkpoint's model config, so serving builds the same model
    model_overrides: dict[str, Any] = field(default_factory=dict)
    half: bool = False  # store float16 weights in the final checkpoint
    # bf16 autocast of the forward pass on CUDA (no effect on CPU, which always runs float32);
    # the protocol's device check trains with it off to pair the two numeric paths
    amp: bool = True
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    # after training, recompute BatchNorm statistics over this many batches of (un-augmented)
    # training windows (precise_bn.py); 0 = off, the STAG recipe's exponential averages
    precise_bn: int = 0


@dataclass
class TrainData:
    """Arrays the loop needs; build with ``prepare_data`` from STAG files."""

    calibrated: np.ndarray  # (N, H, W) float32 in [0, 1], the sensor's frames
    labels: np.ndarray  # (N,) int64 class index
    recording_id: np.ndarray  # (N,) int64, globally unique
    train_valid: np.ndarray  # (N,) bool: frames allowed in training tuples
    heldout_valid: np.ndarray  # (N,) bool: valid frames of held-out recordings (may be empty)
    classes: list[str]
    fingerprint: str = ""
    calibration: dict[str, Any] = field(default_factory=dict)
    heldout_recordings: list[str] = field(default_factory=list)  # names, for the report
    positives: str = "valid"  # which frames train_valid holds (prepare_data's ``positives``)
    train_anchors: np.ndarray | None = None  # (N,) bool, default: train_valid

    def train_sampler(self, k: int, mode: str, seed: int) -> Any:
        """The TupleSampler over the training frames (held-out recordings never appear)."""
        sampler = TupleSampler(
            self.calibrated,
            self.recording_id,
            self.train_valid,
            anchors=self.train_anchors,
            k=k,
            mode=mode,
            seed=seed,
        )
        if len(sampler) == 0:
            raise ValueError("no training tuples: no valid frames outside the held-out recordings")
        return sampler


# -- data -----------------------------------------------------------------------------------


def holdout_recordings(data: Any, spec: str) -> list[int]:
    """Recording ids named by ``spec`` (evaluated on a combined ``StagData``).

    ``none``                       nothing held out
    ``one-per-object@SUBSTR``      for every object, the lowest-id recording with valid
                                   frames among files whose path contains SUBSTR (fold A of
                                   the protocol, ``protocol.py``)
    ``last-per-object@SUBSTR``     the same with the highest-id recording (fold B)
    ``recordings@A,B,...``         recordings by name (as in ``data.recordings``) or id
    """
    spec = (spec or "none").strip()
    if spec == "none":
        return []
    kind, _, arg = spec.partition("@")
    if kind in ("one-per-object", "last-per-object"):
        pick = min if kind == "one-per-object" else max
        srcs = [i for i, s in enumerate(data.sources) if arg in s]
        if not srcs:
            raise ValueError(f"holdout {spec!r}: no --data path contains {arg!r}")
        m = np.isin(data.subset, srcs) & data.valid
        out = []
        for obj in np.unique(data.object_id[m]):
            out.append(int(pick(data.recording_id[m & (data.object_id == obj)])))
        return sorted(out)
    if kind == "recordings":
        out = []
        for tok in (t.strip() for t in arg.split(",") if t.strip()):
            if tok.isdigit():
                out.append(int(tok))
            elif tok in data.recordings:
                out.append(data.recordings.index(tok))
            else:
                raise ValueError(f"holdout: unknown recording {tok!r}")
        return sorted(set(out))
    raise ValueError(
        f"unknown holdout spec {spec!r} "
        "(none | one-per-object@SUBSTR | last-per-object@SUBSTR | recordings@..)"
    )


def load_data(paths: Sequence[str | os.PathLike[str]], profile: Any = None) -> Any:
    """Load and combine STAG files (the data engineer's reader) or ``.npz`` files of your own
    sensor (``npz_io.py``; ``profile`` checks their frame shape). Combined files must share
    their class list."""
    from tactus_memory.training.data import combine, load_stag
    from tactus_memory.training.npz_io import load_npz

    parts = [load_npz(p, profile) if str(p).endswith(".npz") else load_stag(p) for p in paths]
    return parts[0] if len(parts) == 1 else combine(parts)


POSITIVES = ("valid", "contact")
BALANCE = ("none", "recording", "class")


def draw_weights(anchor_key: np.ndarray) -> np.ndarray:
    """(T,) group key per tuple (recording or class) -> (T,) weights, each group summing to 1."""
    _, inv, counts = np.unique(anchor_key, return_inverse=True, return_counts=True)
    return 1.0 / counts[inv].astype(np.float64)


def prepare_data(
    data: Any, holdout: list[int], positives: str = "valid", profile: Any = None
) -> TrainData:
    """Calibrate with ``profile`` (default STAG_GLOVE), gate the dynamic range, split off the
    held-out recordings.

    ``positives``: ``valid`` trains on the dataset's valid-labelled frames; ``contact`` adds
    every frame in contact (``touch/windows.py`` rule) of the training recordings (each
    recording is one object). Held-out scoring always uses the valid frames."""
    from tactus_memory.touch.profile import STAG_GLOVE
    from tactus_memory.touch.windows import (
        CONTACT_MIN_TAXELS,
        contact_taxels,
        estimate_contact_level,
    )

    if positives not in POSITIVES:
        raise ValueError(f"positives must be one of {POSITIVES}, got {positives!r}")
    profile = STAG_GLOVE if profile is None else profile

    # per source file: a badly scaled file pooled with good ones must still fail loudly
    data.check_dynamic_range(profile)  # raises DynamicRangeError naming the file
    cal = data.calibrated(profile)
    held = np.isin(data.recording_id, np.asarray(holdout, dtype=np.int64))
    if (
        profile.contact_level is None
        and profile.name != STAG_GLOVE.name
        and (data.valid & ~held).any()
    ):
        # another sensor's idle rule: its contact level from its own training grasps (the
        # glove keeps its measured 1/6, which the same rule reproduces), in the checkpoint
        level = estimate_contact_level(cal[data.valid & ~held])
        profile = replace(profile, contact_level=level)
    return TrainData(
        calibrated=cal,
        labels=np.asarray(data.object_id, dtype=np.int64),
        recording_id=np.asarray(data.recording_id, dtype=np.int64),
        train_valid=(
            data.valid | (contact_taxels(cal, profile) >= CONTACT_MIN_TAXELS)
            if positives == "contact"
            else data.valid
        )
        & ~held,
        heldout_valid=data.valid & held,
        classes=list(data.objects),
        fingerprint=data.fingerprint(),
        calibration=profile.to_dict(),
        heldout_recordings=[data.recordings[r] for r in holdout],
        positives=positives,
    )


# -- evaluation -----------------------------------------------------------------------------


@torch.inference_mode()
def embed_windows(
    model: TactusModel, windows: np.ndarray, batch: int = 256, device: str = "cpu"
) -> np.ndarray:
    """windows: (B, K, H, W) calibrated -> (B, D) float32 unit rows."""
    model.eval()
    return batched_forward(model, windows, batch, device, model.cfg.out_dim)


def evaluate(
    model: TactusModel,
    targets: np.ndarray,
    data: TrainData,
    mask: np.ndarray,
    *,
    k: int = 8,
    seed: int = EVAL_SEED,
    device: str = "cpu",
) -> dict[str, Any]:
    """Top-1/top-3 on fixed-seed cluster tuples of the frames in ``mask``, plus recording-level
    top-1 (up to 64 valid frames per recording, tiled into K-frame windows, mean embedding)."""
    if not mask.any():
        return {}
    sampler = TupleSampler(data.calibrated, data.recording_id, mask, k=k, seed=seed)
    idx = sampler.fixed(seed)
    z = embed_windows(model, data.calibrated[idx], device=device)
    y = data.labels[idx[:, 0]]
    sim = z @ targets.T
    rec_pred, rec_true, per_rec = [], [], {}
    for r in np.unique(data.recording_id[mask]):
        fr = np.flatnonzero(mask & (data.recording_id == r))
        wins = recording_windows(fr, k)  # (W, k) frame indices, up to RECORDING_POOL frames
        emb = embed_windows(model, data.calibrated[wins], device=device).mean(axis=0)
        pred = int(np.argmax(targets @ emb))
        rec_pred.append(pred)
        rec_true.append(int(data.labels[fr[0]]))
        used = min(len(fr), RECORDING_POOL)
        per_rec[int(r)] = {"true": rec_true[-1], "pred": pred, "frames": used}
    rec_pred_a, rec_true_a = np.array(rec_pred), np.array(rec_true)
    n_cls = len(targets)
    return {
        "tuples": int(len(y)),
        "top1": topk_accuracy(sim, y, 1),
        "top3": topk_accuracy(sim, y, 3),
        "recordings": int(len(rec_true)),
        "recording_top1": float((rec_pred_a == rec_true_a).mean()),
        "chance_top1": 1.0 / n_cls,
        "per_recording": per_rec,
    }


# -- training -------------------------------------------------------------------------------


def refresh_bn(
    model: TactusModel, sampler: Any, frames: torch.Tensor, cfg: TrainConfig, device: str
) -> None:
    """Precise BN: the BatchNorm statistics over ``cfg.precise_bn`` batches of ``cfg.batch``
    training tuples (frames (N, H, W) float32; a fixed draw, no augmentation)."""
    from tactus_memory.training.precise_bn import recompute_bn_stats

    rng = np.random.default_rng([cfg.seed, 0x42])  # fixed: the same statistics on a rerun
    drawn = sampler.sample(rng)  # (T, K)
    rows = rng.choice(len(drawn), size=min(len(drawn), cfg.precise_bn * cfg.batch), replace=False)
    batches = (
        frames[torch.from_numpy(drawn[rows[s : s + cfg.batch]])].to(device)  # (B, K, H, W)
        for s in range(0, len(rows), cfg.batch)
    )
    recompute_bn_stats(model, batches)


def _resolve_device(device: str) -> str:
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


def _ddp_setup(device: str) -> tuple[int, int]:
    """(rank, world) under torchrun on CUDA; (0, 1) otherwise. Untested here (no GPU)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and device.startswith("cuda"):  # pragma: no cover - needs GPUs
        import torch.distributed as dist

        dist.init_process_group("nccl")
        rank = dist.get_rank()
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
        return rank, world
    return 0, 1


def fit(
    data: TrainData,
    targets: Targets,
    cfg: TrainConfig,
    out: str | os.PathLike[str],
    *,
    space_dim: int,
    pretrained: str | os.PathLike[str] | None = None,
    device: str = "auto",
    resume: bool = False,
    progress: bool = True,
    extra_loss: ExtraLoss | None = None,
    extra_args: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Train, evaluate on the held-out frames (if any), save ``out`` (.safetensors).

    ``extra_loss`` is added to the cross-entropy on every step (same tuples, same augmented
    batch); ``extra_args`` are recorded in the checkpoint's ``train_args`` (distillation puts
    its teachers there). Returns the summary written into the checkpoint's ``metrics``.
    """
    if cfg.balance not in BALANCE:
        raise ValueError(f"balance must be one of {BALANCE}, got {cfg.balance!r}")
    if not 0.0 <= cfg.consecutive <= 1.0:
        raise ValueError(f"consecutive must be in [0, 1], got {cfg.consecutive}")
    device = _resolve_device(device)
    rank, world = _ddp_setup(device)
    torch.manual_seed(cfg.seed)
    shape = tuple(data.calibrated.shape[-2:])  # the sensor's (H, W): the stem adapts to it
    overrides = {"frame_shape": shape, **cfg.model_overrides}
    model = create_model(cfg.model, out_dim=space_dim, frames=cfg.k, **overrides)
    model = model.to(device)
    a = cfg.augment
    if model.cfg.input_gamma < 1.0 and a.noise_std > 0 and a.noise_on_zero:
        raise ValueError(
            f"input_gamma {model.cfg.input_gamma} < 1 turns augmentation noise on empty taxels "
            f"({a.noise_std}) into ~{a.noise_std**model.cfg.input_gamma:.2f}: train with "
            "noise only on pressed taxels (--augment pressed-noise, noise_on_zero=False)"
        )
    mae_meta = None
    if pretrained:
        mae_meta = load_pretrained_trunk(model.trunk, pretrained, model.cfg)
        overlap = set(mae_meta.get("excluded_recordings", []))
        held = set(np.unique(data.recording_id[data.heldout_valid]).tolist())
        if held - overlap:
            log.warning(
                "pretrained trunk did not exclude held-out recordings %s: validation is optimistic",
                sorted(held - overlap),
            )
    net: torch.nn.Module = model
    if world > 1:  # pragma: no cover - needs GPUs
        net = torch.nn.parallel.DistributedDataParallel(model)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    amp = autocast(device, cfg.amp)
    tgt = torch.from_numpy(np.ascontiguousarray(targets.centred, np.float32)).to(device)

    sampler = data.train_sampler(cfg.k, cfg.sampling, cfg.seed)
    frames = torch.from_numpy(np.ascontiguousarray(data.calibrated, np.float32))
    labels = torch.from_numpy(data.labels)
    gen = torch.Generator().manual_seed(cfg.seed * 1000 + rank)

    out = Path(out)
    state_path = resume_path(out)
    step, history = 0, []
    if resume and state_path.exists():
        step, history = load_resume(state_path, module=model, opt=opt, gen=gen, device=device)
        log.info("resumed training at step %d", step)

    tuples, weights, epoch = None, None, -1
    t0, ema_loss, ema_acc = time.perf_counter(), None, None
    steps_this_run = 0
    bar = tqdm(total=cfg.steps, initial=step, desc="train", disable=not progress or rank != 0)
    model.train()
    while step < cfg.steps:
        if step // cfg.resample_every != epoch:  # redraw tuples (deterministic per epoch)
            epoch = step // cfg.resample_every
            rng = np.random.default_rng([cfg.seed, epoch])
            drawn = sampler.sample(rng)  # (T, K)
            if cfg.consecutive > 0:
                swap = rng.random(len(drawn)) < cfg.consecutive
                drawn[swap] = consecutive_windows(drawn[swap, 0], data.recording_id, cfg.k, rng)
            tuples = torch.from_numpy(drawn)
            if cfg.balance != "none":
                key = data.labels if cfg.balance == "class" else data.recording_id
                weights = torch.from_numpy(draw_weights(key[drawn[:, 0]]))
        for g in opt.param_groups:
            g["lr"] = lr_at(step, cfg.steps, cfg.warmup, cfg.lr)
        if cfg.balance == "none":
            rows = torch.randint(0, len(tuples), (cfg.batch,), generator=gen)
        else:
            rows = torch.multinomial(weights, cfg.batch, replacement=True, generator=gen)
        idx = tuples[rows]  # (B, K)
        x = augment(frames[idx], cfg.augment, gen).to(device)  # (B, K, H, W)
        y = labels[idx[:, 0]].to(device)
        with amp:
            z = net(x)
        logits = (z.float() @ tgt.T) / TEMPERATURE
        loss = F.cross_entropy(logits, y)
        if extra_loss is not None:
            loss = loss + extra_loss(x, z.float())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        steps_this_run += 1
        lv = float(loss.detach())
        acc = float((logits.argmax(1) == y).float().mean())
        ema_loss = lv if ema_loss is None else 0.95 * ema_loss + 0.05 * lv
        ema_acc = acc if ema_acc is None else 0.95 * ema_acc + 0.05 * acc
        if step % 25 == 0 or step == cfg.steps:
            history.append({"step": step, "loss": ema_loss, "acc": ema_acc})
        bar.set_postfix(loss=f"{ema_loss:.3f}", acc=f"{ema_acc:.2f}")
        bar.update(1)
        if rank == 0 and (step % cfg.save_every == 0 or step == cfg.steps):
            save_resume(state_path, module=model, opt=opt, gen=gen, step=step, history=history)
    bar.close()
    if cfg.precise_bn > 0:
        refresh_bn(model, sampler, frames, cfg, device)
    wall = time.perf_counter() - t0
    summary: dict[str, Any] = {
        "steps": step,
        "steps_this_run": steps_this_run,
        "wall_s_this_run": round(wall, 1),
        "steps_per_s": round(steps_this_run / wall, 3) if steps_this_run else None,
        "train_loss_ema": ema_loss,
        "train_acc_ema": ema_acc,
        "params": param_report(model),
        "train_tuples_per_draw": len(sampler),
        "device": device,
        "pretrained": str(pretrained) if pretrained else None,
        "precise_bn_batches": cfg.precise_bn,
    }
    if rank != 0:  # pragma: no cover - needs GPUs
        return summary
    if data.heldout_valid.any():
        ev = evaluate(model, targets.centred, data, data.heldout_valid, k=cfg.k, device=device)
        summary["heldout"] = {k: v for k, v in ev.items() if k != "per_recording"}
        summary["heldout"]["recordings_named"] = data.heldout_recordings
        summary["heldout_per_recording"] = ev["per_recording"]
    train_args = {**asdict(cfg), "positives": data.positives, **(extra_args or {})}
    save_checkpoint(
        out,
        model,
        targets,
        space_dim=space_dim,
        calibration=data.calibration,
        fingerprint=data.fingerprint,
        seed=cfg.seed,
        steps=step,
        metrics={k: v for k, v in summary.items() if k != "heldout_per_recording"},
        train_args=train_args,
        target_geometry=target_report(targets),
        half=cfg.half,
    )
    hist_path = out.with_name(out.stem + ".history.json")
    hist_path.write_text(json.dumps({"summary": summary, "history": history}, indent=1) + "\n")
    return summary
