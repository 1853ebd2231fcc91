#!/usr/bin/env bash
# The GPU recipe in one command (checkpoints README, "GPU recipe"): MAE for the r18 teacher and
# the lite student, r18 teacher seeds side by side on one GPU, their ensemble distilled into
# tactus-lite, and the protocol (2 folds x 3 seeds, paired against the shipped recipe) for
# teacher, student and the lite recipes, all as one plan (tactus_memory/training/plans/
# gpu.json) run by the protocol runner with a deadline; then the results are packed into OUT.
#
#   STAG=path/to/stag bash scripts/gpu_recipe.sh OUT          # on the GPU machine
#   STAG=... DEVICE=cpu MAX_STEPS=3 SEEDS=0 SWAP=tactus-r18=tactus-tiny bash scripts/gpu_recipe.sh OUT
#                                                             # the CPU smoke test (tests/)
# Environment: STAG (folder with weights_lite/ and blindfolded_lite_train/), PLAN (gpu), JOBS
# (processes at a time, 20), ONLY (space-separated recipes to run, with what they need), DEADLINE_S (runner deadline, 450: the whole command stays inside
# 9 minutes), DEVICE (auto), PYTHON (python3), WORK (where runs are written: the teachers stay
# there, too big to carry), MAX_STEPS / SEEDS / SWAP / FOLDS (smoke test only).
#
# OUT receives at most 8 files, none over 16 MB: results.tar.gz (every run's result JSON, log,
# the report, status and budget), final.tar (the student and strong checkpoints trained on all
# data, with sidecars) and one <recipe>-folds.tar per lite recipe (float16 fold checkpoints,
# for the stream metrics computed afterwards on CPU: `tactus eval-recipe stream`).
set -uo pipefail
OUT_DIR=$(mkdir -p "${1:?usage: gpu_recipe.sh OUT}" && cd "$1" && pwd)
cd "$(dirname "$0")/.."
STAG=${STAG:-.stag}
PY=${PYTHON:-python3}
WORK=${WORK:-runs/gpu_recipe}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 OMP_WAIT_POLICY=PASSIVE
mkdir -p "$OUT_DIR" "$WORK"
args=(--plan "${PLAN:-gpu}" --out "$WORK" --jobs "${JOBS:-20}" --device "${DEVICE:-auto}"
  --data "$STAG/weights_lite" --data "$STAG/blindfolded_lite_train"
  --targets-from tactus_memory/touch/checkpoints/tactus-lite-minilm.safetensors
  --deadline-s "${DEADLINE_S:-450}")
[ -n "${MAX_STEPS:-}" ] && args+=(--max-steps "$MAX_STEPS")
[ -n "${SEEDS:-}" ] && args+=(--seeds "$SEEDS")
[ -n "${SWAP:-}" ] && args+=(--swap-model "$SWAP")
[ -n "${FOLDS:-}" ] && args+=(--folds "$FOLDS")
for r in ${ONLY:-}; do args+=(--only "$r"); done
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
"$PY" -m tactus_memory.training.protocol_run run "${args[@]}" 2>&1 | tee "$WORK/runner.log"
rc=${PIPESTATUS[0]}

# pack: JSON and logs, then the checkpoints that serving or the CPU stream metrics need
(cd "$WORK" && find . \( -name '*.json' -o -name '*.log' -o -name 'report.md' \) -print0 |
  tar -czf "$OUT_DIR/results.tar.gz" --null -T -)
finals=$(cd "$WORK" && ls student/all-*.safetensors strong/all-*.safetensors 2>/dev/null)
[ -n "$finals" ] && (cd "$WORK" && tar -cf "$OUT_DIR/final.tar" $finals ${finals//.safetensors/.json})
for r in student strong shipped; do
  folds=$(cd "$WORK" && ls $r/A-*.safetensors $r/B-*.safetensors 2>/dev/null)
  [ -n "$folds" ] && (cd "$WORK" && tar -cf "$OUT_DIR/$r-folds.tar" $folds)
done
ls -la "$OUT_DIR"
exit "$rc"
