"""The touch training ladder (issue 13): every rung's held-out scores in one JSON.

    python benchmarks/touch_ladder.py RUNS_DIR [--out benchmarks/results/touch_ladder.json]

For every ``RUNS_DIR/<rung>_s<seed>.safetensors`` written by ``tactus train ... --holdout
one-per-object@blindfolded`` (the commands are in ``LADDER`` below and in the checkpoints
README), reads the held-out tuple/recording top-1 the training run recorded, then runs the
real stream evaluation (``touch/training/stream_eval.py``: real memory, MiniLM, both storage modes)
over the 26 held-out blindfolded recordings, and writes per-run figures plus the mean of the
seeds per rung. STAG files come from ``$TACTUS_STAG_DIR`` (default ``../shared/data/stag``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HOLDOUT = "one-per-object@blindfolded"
#: rung -> the `tactus train` options that differ from the baseline (400 steps, batch 64,
#: lr 1e-3, tactus-lite, MiniLM, no MAE, --threads 1); run with --seed 0 and --seed 1
LADDER: dict[str, str] = {
    "val": "",
    "val_contact": "--positives contact",
    "bal": "--balance recording",
    "cls": "--balance class",
    "balcons": "--balance recording --consecutive 0.5",
    "cbc1": "--positives contact --balance recording --consecutive 1.0",
    "cb": "--positives contact --balance recording",
    "strong": "--augment strong",
    "strongwd": "--augment strong --weight-decay 0.3",
    "blind": "--positives contact, and only --data $STAG/blindfolded_lite_train",
    "shaped": "--input-gamma 0.3 --input-blur 1.0 --augment pressed-noise",
    "short": "--steps 150",
    # issue 22, the paper's ladder on CPU: MAE 1,500 steps at batch 256 (`tactus pretrain
    # --steps 1500 --batch 256`, same holdout), then 2,000 steps; results in touch_ladder_ii.json
    "lite_strong": "--pretrained MAE(tactus-lite, 1500x256) --augment strong --steps 2000",
    "mid_strong": "--model tactus-mid --pretrained MAE(tactus-mid, 1500x256) --augment strong "
    "--steps 2000",
    "lite_mae": "--pretrained MAE(tactus-lite, 1500x256) --steps 600",
    "mid_mae": "--model tactus-mid --pretrained MAE(tactus-mid, 1500x256) --steps 600",
    "lite_distill": "tactus distill --teacher mid_mae_s0 --cosine-weight 1.0 --pretrained "
    "MAE(tactus-lite, 1500x256) --steps 600",
}
KEYS = ("r@1", "r@5", "mrr", "match_other_object_rate", "last_correct", "count_exact")


def score_run(ckpt: Path, data: Any) -> dict[str, Any]:
    from tactus_memory.training.stream_eval import run_stream_eval

    meta = json.loads(ckpt.with_suffix(".json").read_text())
    held = meta.get("metrics", {}).get("heldout", {})
    t0 = time.perf_counter()
    res = run_stream_eval(ckpt, data, HOLDOUT)
    out = {
        "tuple_top1": held.get("top1"),
        "recording_top1": held.get("recording_top1"),
        "train_args": {
            k: meta.get("train_args", {}).get(k)
            for k in ("steps", "positives", "balance", "consecutive", "weight_decay")
        },
        "model": {k: meta["model"].get(k) for k in ("input_gamma", "input_blur", "dropout")},
        "leakage": res["leakage"]["status"],
        "eval_s": round(time.perf_counter() - t0, 1),
    }
    for k in KEYS:
        out[f"stream_{k}"] = res["served"].get(k)
    out["stream_idle_pass_all_windows"] = res["all_windows"].get("match_idle_rate")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/touch_ladder.json")
    args = ap.parse_args()
    from tactus_memory.training.train import load_data

    stag = Path(os.environ.get("TACTUS_STAG_DIR", ROOT.parent / "shared/data/stag"))
    data = load_data([stag / "weights_lite", stag / "blindfolded_lite_train"])
    runs: dict[str, Any] = {}
    for ck in sorted(args.runs.glob("*_s[0-9].safetensors")):
        runs[ck.stem] = score_run(ck, data)
        print(ck.stem, {k: round(v, 3) for k, v in runs[ck.stem].items() if isinstance(v, float)})
    rungs: dict[str, Any] = {}
    for name in sorted({re.sub(r"_s\d$", "", r) for r in runs}):
        mine = [v for r, v in runs.items() if re.sub(r"_s\d$", "", r) == name]
        num = [k for k, v in mine[0].items() if isinstance(v, float)]
        rungs[name] = {
            "seeds": len(mine),
            "options": LADDER.get(name),
            **{k: float(np.mean([m[k] for m in mine if m[k] is not None])) for k in num},
            # the seed spread the ship decision is judged against (checkpoints README)
            "spread": {
                k: [float(min(m[k] for m in mine)), float(max(m[k] for m in mine))]
                for k in num
                if all(m[k] is not None for m in mine)
            },
        }
    base = "tactus train --data $STAG/weights_lite --data $STAG/blindfolded_lite_train "
    payload = {
        "what": "touch training ladder on --holdout one-per-object@blindfolded (26 recordings): "
        "held-out tuple/recording top-1 from training, stream metrics (served mode: idle windows "
        "not stored) from the real memory; idle pass rate with every window embedded",
        "command": base + "--out runs/RUNG_sS.safetensors --model tactus-lite --space minilm "
        "--steps 400 --batch 64 --lr 1e-3 --seed S --holdout one-per-object@blindfolded "
        "--threads 1 OPTIONS; python benchmarks/touch_ladder.py runs/",
        "rungs": rungs,
        "runs": runs,
    }
    args.out.write_text(json.dumps(payload, indent=1) + "\n")
    print("wrote", args.out)


if __name__ == "__main__":
    main()
