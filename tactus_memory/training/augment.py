"""Training augmentation for calibrated grasp windows ``(B, K, 32, 32)``.

Spatial: the 548 real taxels sit at fixed places on the 32x32 raster (stag-format.md), so
only small rigid translations (+-1 px: registration jitter of the glove on the hand) and a
global intensity gain (grip force) are used; no flips or rotations, which would move taxels
onto pixels that are never sensors. Gaussian noise std 0.015 after calibration follows the
STAG reference implementation.

Temporal: tuple members are cluster-sampled configurations, not consecutive frames, so their
order carries no meaning; shuffling it teaches the fusion layer that. Randomly dropping frames
(replacing them by copies of other frames in the window) mimics short windows, which are
padded the same way at inference.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

NOISE_STD = 0.015  # STAG reference code: Gaussian noise after calibration (train only)


@dataclass
class AugmentConfig:
    max_shift: int = 1  # max |dx|, |dy| in pixels of a rigid translation (same for all K frames)
    p_shift: float = 0.5  # probability a window is translated
    gain: float = 0.1  # intensity gain drawn from U(1 - gain, 1 + gain) per window
    noise_std: float = NOISE_STD  # additive Gaussian noise per pixel
    shuffle: bool = True  # permute frame order within each window
    p_drop: float = 0.3  # probability a window loses frames (replaced by repeats of others)
    max_drop: int = 4  # at most this many frames replaced in a dropped window
    taxel_drop: float = 0.0  # share of pixels zeroed per window (dead or lifted taxels)
    # noise on unpressed (zero) pixels too; False for models that compress pressure
    # (input_gamma < 1 turns noise of 0.015 on an empty taxel into ~0.28)
    noise_on_zero: bool = True


#: named settings for ``tactus train --augment``: "default" (above) and "strong" (against
#: memorising two recordings per class: larger shifts and gain, more noise, taxel dropout)
AUGMENT_PRESETS: dict[str, AugmentConfig] = {
    "default": AugmentConfig(),
    "strong": AugmentConfig(
        max_shift=2, p_shift=0.8, gain=0.3, noise_std=0.03, p_drop=0.5, taxel_drop=0.1
    ),
    "pressed-noise": AugmentConfig(noise_on_zero=False),
}


def augment_preset(name: str) -> AugmentConfig:
    """The named preset (a fresh copy); ValueError naming the choices for an unknown name."""
    if name not in AUGMENT_PRESETS:
        raise ValueError(f"augment must be one of {sorted(AUGMENT_PRESETS)}, got {name!r}")
    return replace(AUGMENT_PRESETS[name])


def _shift(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """x: (K, H, W) -> translated by (dy, dx), edge-replicated."""
    if dy == 0 and dx == 0:
        return x
    h, w = x.shape[-2:]
    p = max(abs(dy), abs(dx))
    xp = torch.nn.functional.pad(x[None], (p, p, p, p), mode="replicate")[0]
    return xp[:, p - dy : p - dy + h, p - dx : p - dx + w]


def augment(x: torch.Tensor, cfg: AugmentConfig, gen: torch.Generator) -> torch.Tensor:
    """x: (B, K, 32, 32) calibrated float32 -> augmented copy, same shape, values >= 0."""
    b, k = x.shape[:2]
    dev = x.device
    out = x.clone()
    if cfg.max_shift > 0 and cfg.p_shift > 0:
        do = torch.rand(b, generator=gen) < cfg.p_shift
        d = torch.randint(-cfg.max_shift, cfg.max_shift + 1, (b, 2), generator=gen)
        for i in torch.nonzero(do).flatten().tolist():
            out[i] = _shift(out[i], int(d[i, 0]), int(d[i, 1]))
    if cfg.gain > 0:
        g = 1.0 + (torch.rand(b, 1, 1, 1, generator=gen) * 2 - 1) * cfg.gain
        out = out * g.to(dev)
    if k > 1 and cfg.shuffle:
        perm = torch.argsort(torch.rand(b, k, generator=gen), dim=1).to(dev)
        out = torch.gather(out, 1, perm[:, :, None, None].expand_as(out))
    if k > 1 and cfg.p_drop > 0:
        drop = torch.rand(b, generator=gen) < cfg.p_drop
        for i in torch.nonzero(drop).flatten().tolist():
            n = int(torch.randint(1, min(cfg.max_drop, k - 1) + 1, (1,), generator=gen))
            slots = torch.randperm(k, generator=gen)
            lost, kept = slots[:n], slots[n:]
            src = kept[torch.randint(0, len(kept), (n,), generator=gen)]
            out[i, lost.to(dev)] = out[i, src.to(dev)]
    if cfg.noise_std > 0:
        noise = (torch.randn(out.shape, generator=gen) * cfg.noise_std).to(dev)
        out = out + (noise if cfg.noise_on_zero else noise * (out > 0))
    if cfg.taxel_drop > 0:
        lost = torch.rand(b, 1, *out.shape[2:], generator=gen) < cfg.taxel_drop
        out = out.masked_fill(lost.to(dev), 0.0)
    return out.clamp_(min=0.0)
