"""Checkpoints: safetensors weights + JSON metadata (embedded, and mirrored in a sidecar).

One ``.safetensors`` file holds everything needed to use the encoder without the data:

    tensors   model.*               the TactusModel state dict (float32, or float16 if ``half``)
              targets.raw           (C, D) template-averaged class-phrase embeddings
              targets.centred       (C, D) normalize(raw - centroid): what logits use
              targets.centroid      (D,)   removed from text queries (query_transform)
    metadata  "tactus"              JSON: format, model config, space name/dim, classes,
                                    phrases, calibration profile, data fingerprint, seed, code
                                    version, steps, validation metrics, target geometry

``<stem>.json`` beside the weights repeats the metadata for humans and tools; the embedded
copy is authoritative. The file's sha256 is the provenance handle (``file_sha256``).

torch is imported only by what needs it (saving, rebuilding the model, resume state):
``load_checkpoint(path, weights=False)`` reads the metadata and targets without it, for a
server that runs the encoder on ONNX Runtime (:mod:`tactus_memory.spaces.onnx_runtime`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from safetensors import safe_open

from tactus_memory import __version__
from tactus_memory.hashing import file_sha256
from tactus_memory.touch.targets import Targets

if TYPE_CHECKING:
    import torch

    from tactus_memory.touch.model import TactusModel

FORMAT = "tactus-touch/1"
DEFAULT_CHECKPOINT = "tactus-lite-minilm.safetensors"  # in tactus_memory/touch/checkpoints/
#: the demo's checkpoint (``tactus demo``): trained with ``--holdout one-per-object@blindfolded``,
#: so the recordings the demo asks about are ones it never trained on (its metadata names them)
DEMO_CHECKPOINT = "tactus-lite-minilm-demo.safetensors"


def _shipped(name: str) -> Path:
    ref = resources.files("tactus_memory.touch") / "checkpoints" / name
    path = Path(str(ref))
    if not path.is_file():
        raise FileNotFoundError(
            f"the shipped touch checkpoint {name} is missing from {path.parent}; "
            "train one with `tactus train` and use TactusEncoder.from_pretrained(path)"
        )
    return path


def default_checkpoint_path() -> Path:
    """The shipped default checkpoint (package data)."""
    return _shipped(DEFAULT_CHECKPOINT)


def demo_checkpoint_path() -> Path:
    """The shipped demo checkpoint (package data; trained without the demo's recordings)."""
    return _shipped(DEMO_CHECKPOINT)


#: the prior score calibrations of the shipped checkpoints (``search/scoring.py``), keyed by
#: checkpoint sha256; written by ``benchmarks/calibration_prior.py``
CALIBRATION_PRIORS = "calibration-priors.json"


def calibration_prior(sha256: str) -> dict[str, float] | None:
    """The prior score calibration (``{"mu", "sigma"}`` of the probe null) shipped for the
    checkpoint of ``sha256`` (None: none shipped)."""
    ref = resources.files("tactus_memory.touch") / "checkpoints" / CALIBRATION_PRIORS
    path = Path(str(ref))
    if not path.is_file():
        return None
    row = json.loads(path.read_text()).get("priors", {}).get(sha256)
    return None if row is None else {"mu": float(row["mu"]), "sigma": float(row["sigma"])}


#: the measured precision of a touch match at the grasp bar, keyed by checkpoint sha256;
#: written by ``benchmarks/touch_demo.py`` (held-out recordings of the protocol's fold A)
MATCH_PRECISION = "match-precision.json"


def match_precision(sha256: str) -> dict[str, Any] | None:
    """The measured precision at the match bar of the checkpoint of ``sha256`` (None: none)."""
    path = Path(str(resources.files("tactus_memory.touch") / "checkpoints" / MATCH_PRECISION))
    if not path.is_file():
        return None
    row = json.loads(path.read_text()).get("precision_at_bar", {}).get(sha256)
    return None if row is None else dict(row)


def heldout_recordings(meta: dict[str, Any]) -> list[str]:
    """The recordings a checkpoint was trained WITHOUT, as its metadata records them (the
    ``--holdout`` of ``tactus train``; empty for a checkpoint trained on everything)."""
    return list(meta.get("metrics", {}).get("heldout", {}).get("recordings_named", []))


@dataclass
class Checkpoint:
    """A loaded checkpoint. ``model`` is in eval mode, float32, on ``device`` (None when
    loaded with ``weights=False``)."""

    model: TactusModel | None
    meta: dict[str, Any]
    targets: Targets
    sha256: str
    path: Path
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def space_name(self) -> str:
        return str(self.meta["space"]["name"])

    @property
    def dim(self) -> int:
        return int(self.meta["space"]["dim"])

    @property
    def classes(self) -> list[str]:
        return list(self.meta["classes"])


def save_checkpoint(
    path: str | os.PathLike[str],
    model: TactusModel,
    targets: Targets,
    *,
    space_dim: int,
    calibration: dict[str, Any] | None = None,
    fingerprint: str = "",
    seed: int | None = None,
    steps: int = 0,
    metrics: dict[str, Any] | None = None,
    train_args: dict[str, Any] | None = None,
    target_geometry: dict[str, Any] | None = None,
    half: bool = False,
) -> str:
    """Write weights + metadata atomically; returns the file's sha256."""
    import torch
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    dtype = torch.float16 if half else torch.float32
    tensors: dict[str, torch.Tensor] = {}
    for k, v in model.state_dict().items():
        v = v.detach().cpu()
        tensors[f"model.{k}"] = (v.to(dtype) if v.is_floating_point() else v).contiguous()
    tensors["targets.raw"] = torch.from_numpy(np.ascontiguousarray(targets.raw, np.float32))
    tensors["targets.centred"] = torch.from_numpy(np.ascontiguousarray(targets.centred, np.float32))
    tensors["targets.centroid"] = torch.from_numpy(
        np.ascontiguousarray(targets.centroid, np.float32)
    )
    space_meta: dict[str, Any] = {"name": targets.space_name, "dim": int(space_dim)}
    if targets.space_fingerprint:
        space_meta["fingerprint"] = targets.space_fingerprint
    meta = {
        "format": FORMAT,
        "model": model.cfg.to_dict(),
        "space": space_meta,
        "classes": list(targets.classes),
        "phrases": list(targets.phrases),
        "calibration": calibration or {},
        "data_fingerprint": fingerprint,
        "seed": seed,
        "code_version": __version__,
        "steps": int(steps),
        "metrics": metrics or {},
        "train_args": train_args or {},
        "target_geometry": target_geometry or {},
        "weights_dtype": str(dtype).replace("torch.", ""),
    }
    tmp = path.with_name(path.name + ".tmp")
    save_file(tensors, str(tmp), metadata={"tactus": json.dumps(meta, sort_keys=True)})
    os.replace(tmp, path)
    sha = file_sha256(path)
    sidecar = dict(meta, sha256=sha)
    path.with_suffix(".json").write_text(json.dumps(sidecar, indent=2, sort_keys=True) + "\n")
    return sha


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The embedded metadata only (no weights loaded)."""
    with safe_open(str(path), framework="numpy") as f:
        md = f.metadata() or {}
    if "tactus" not in md:
        raise ValueError(f"{path} is not a Tactus checkpoint (no 'tactus' metadata)")
    meta = json.loads(md["tactus"])
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: unsupported checkpoint format {meta.get('format')!r}")
    return meta


def load_checkpoint(
    path: str | os.PathLike[str], device: str = "cpu", *, weights: bool = True
) -> Checkpoint:
    """Rebuild the model (float32, eval mode) and its targets from a ``.safetensors`` file;
    ``weights=False``: the metadata and targets only (no torch, ``model`` None)."""
    path = Path(path)
    meta = read_metadata(path)
    with safe_open(str(path), framework="numpy") as f:
        arrays = {k: f.get_tensor(k) for k in f.keys() if k.startswith("targets.")}  # noqa: SIM118
    model = _rebuild(path, meta, device) if weights else None
    targets = Targets(
        classes=list(meta["classes"]),
        phrases=list(meta["phrases"]),
        raw=arrays["targets.raw"].astype(np.float32),
        centroid=arrays["targets.centroid"].astype(np.float32),
        centred=arrays["targets.centred"].astype(np.float32),
        space_name=str(meta["space"]["name"]),
        space_fingerprint=meta["space"].get("fingerprint"),
    )
    return Checkpoint(model=model, meta=meta, targets=targets, sha256=file_sha256(path), path=path)


def _rebuild(path: Path, meta: dict[str, Any], device: str) -> TactusModel:
    from safetensors.torch import load_file

    from tactus_memory.touch.model import TactusConfig, TactusModel

    tensors = load_file(str(path), device="cpu")
    model = TactusModel(TactusConfig.from_dict(meta["model"]))
    state = {k[len("model.") :]: v for k, v in tensors.items() if k.startswith("model.")}
    state = {k: (v.float() if v.is_floating_point() else v) for k, v in state.items()}
    model.load_state_dict(state, strict=True)
    return model.to(device).eval()


# -- resume state (training loops) -----------------------------------------------------------


def resume_path(out: str | Path) -> Path:
    """Where a run writing ``out`` keeps its resume state (``<out>.resume.pt``)."""
    out = Path(out)
    return out.with_name(out.name + ".resume.pt")


def save_resume(
    path: Path,
    *,
    module: torch.nn.Module,
    opt: torch.optim.Optimizer,
    gen: torch.Generator,
    step: int,
    history: list[dict[str, Any]],
    key: str = "model",
) -> None:
    """Module, optimizer and sampling-generator state, so ``--resume`` continues exactly."""
    import torch

    state = {"opt": opt.state_dict(), "gen": gen.get_state(), "step": step, "history": history}
    state[key] = module.state_dict()
    torch.save(state, path)


def load_resume(
    path: Path,
    *,
    module: torch.nn.Module,
    opt: torch.optim.Optimizer,
    gen: torch.Generator,
    device: str = "cpu",
    key: str = "model",
) -> tuple[int, list[dict[str, Any]]]:
    """Restore what :func:`save_resume` wrote; returns (step, history)."""
    import torch

    st = torch.load(path, map_location=device, weights_only=True)
    module.load_state_dict(st[key])
    opt.load_state_dict(st["opt"])
    gen.set_state(st["gen"])
    return int(st["step"]), list(st["history"])
