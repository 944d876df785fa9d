#!/usr/bin/env bash
# One prepared run for a lent GPU machine (issue 42; docs/gpu.md): at most TOTAL_S seconds of wall time,
# every part under `timeout`, every figure written to $OUT as soon as it is measured, so a cut run still
# leaves what it measured.
#
#   bash benchmarks/device_check.sh                      # from the repository root; OUT defaults to ./device_out
#   DEVICE_CHECK_SMOKE=1 bash benchmarks/device_check.sh # the same steps at tiny sizes (a CPU, ~5 min)
#
# Parts: (0) wheels from .whl/ into $SITE (docs/gpu.md: an offline image lacks jraph, meshio, tyro, pymoo...),
# nvidia-smi, jax.devices(); (a) the README's main job: experiments.train (the cpu preset; generates its data)
# then experiments.evaluate, wall seconds per phase; (b) benchmarks.solver_throughput (cpu and paper meshes);
# (c) benchmarks.gpu_check; (d) benchmarks.startup (cold and warm compilation cache).
# Results: $OUT/phases.tsv (part, exit status, seconds, budget; 124 = cut by its timeout), $OUT/*.log (consoles),
# $OUT/*.json (the benchmarks' figures, rewritten after every row), $OUT/main/ (the run's metrics and notes).
set -u

# ---- budgets [s] (TOTAL_S bounds the whole script; each part also stops at what is left of it) ----
TOTAL_S=${TOTAL_S:-570}
BUDGET_SETUP=${BUDGET_SETUP:-40}        # (0) wheels, nvidia-smi, jax.devices()
BUDGET_TRAIN=${BUDGET_TRAIN:-230}       # (a) data generation + training (cpu preset)
BUDGET_EVAL=${BUDGET_EVAL:-70}          # (a) evaluation of the run (the issue's goal: (a) in 300 s)
BUDGET_SOLVER=${BUDGET_SOLVER:-80}      # (b) solver throughput curve
BUDGET_GPU_CHECK=${BUDGET_GPU_CHECK:-70}  # (c) gpu_check --budget_s (its process gets 10 s more)
BUDGET_STARTUP=${BUDGET_STARTUP:-0}     # (d) start-up, cold and warm cache (0: all that is left of TOTAL_S)

SMOKE=${DEVICE_CHECK_SMOKE:-0}
OUT=${OUT:-./device_out}
PY=${PYTHON:-python3}
SITE=${SITE:-/tmp/site}
WORK=${WORK:-/tmp/pcmgn-device-check}
TRAIN_PRESET=cpu
TRAIN_FLAGS=${TRAIN_FLAGS:-}            # e.g. --num_steps=2000 to shrink the main job (say so in the report)
SOLVER_ARGS="--presets cpu,paper --sizes 1,256,16 --frames 2 --repeats 2"   # 256 right after 1: the goal's ratio
GPU_CHECK_ARGS="--solver_frames 10"
STARTUP_ARGS="--conditions cold,warm --no_prime"   # (a) trained on the data: read cache built
INSTALL=${DEVICE_CHECK_INSTALL:-1}
if [ "$SMOKE" = 1 ]; then               # the same steps, tiny, to prove the script before a GPU shot
  TOTAL_S=${SMOKE_TOTAL_S:-420}; BUDGET_TRAIN=150; BUDGET_EVAL=60; BUDGET_SOLVER=40; BUDGET_GPU_CHECK=60
  BUDGET_STARTUP=0; TRAIN_PRESET=tiny; TRAIN_FLAGS="--num_steps=40 $TRAIN_FLAGS"
  SOLVER_ARGS="--presets tiny --sizes 1,2 --frames 1 --repeats 1"; GPU_CHECK_ARGS="--smoke"
  STARTUP_ARGS="--conditions cold,warm --no_prime --preset tiny"
  INSTALL=${DEVICE_CHECK_INSTALL:-0}    # the wheels are for the GPU image's Python (3.12)
fi

mkdir -p "$OUT" "$WORK"
OUT=$(cd "$OUT" && pwd)
START=$(date +%s.%N)
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg
if [ -z "${PCMGN_JAX_CACHE_DIR:-}" ]; then   # the main job starts with an empty compilation cache
  export PCMGN_JAX_CACHE_DIR=$WORK/jax-cache
  rm -rf "$PCMGN_JAX_CACHE_DIR"
fi
printf 'part\texit\tseconds\tbudget_s\n' > "$OUT/phases.tsv"

left() { "$PY" -c "import sys,time; print(max(0, int($TOTAL_S - (time.time() - $START))))"; }

# run NAME BUDGET CMD...: CMD under `timeout` (its budget or what is left of TOTAL_S), console teed to
# $OUT/NAME.log, one line in phases.tsv as soon as it ends
run() {
  local name=$1 budget=$2; shift 2
  local rest; rest=$(left)
  [ "$budget" -gt "$rest" ] && budget=$rest
  if [ "$budget" -lt 5 ]; then
    printf '%s\tskipped\t0\t%s\n' "$name" "$budget" >> "$OUT/phases.tsv"
    echo "== $name: skipped ($rest s of TOTAL_S=$TOTAL_S left)" | tee "$OUT/$name.log"
    return 0
  fi
  echo "== $name (timeout $budget s): $*" > "$OUT/$name.log"
  local t0 t1 rc
  t0=$(date +%s.%N)
  timeout --kill-after=5 "$budget" "$@" >> "$OUT/$name.log" 2>&1
  rc=$?
  t1=$(date +%s.%N)
  local secs; secs=$("$PY" -c "print(round($t1 - $t0, 2))")
  printf '%s\t%s\t%s\t%s\n' "$name" "$rc" "$secs" "$budget" >> "$OUT/phases.tsv"
  echo "== $name: exit $rc after $secs s (budget $budget s)" >> "$OUT/$name.log"
  tail -n 40 "$OUT/$name.log"
}

# ---- (0) wheels, the device ----
if [ "$INSTALL" = 1 ]; then
  run install "$BUDGET_SETUP" "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir \
      --target "$SITE" .whl/*.whl
  export PYTHONPATH="$SITE:$PWD"
else
  export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
fi
(nvidia-smi || echo "no nvidia-smi") > "$OUT/nvidia-smi.txt" 2>&1
run devices 60 "$PY" -c "import jax, jaxlib; print('jax', jax.__version__, 'jaxlib', jaxlib.__version__); print(jax.devices())"

# ---- (a) the README's main job: train (generates the data) then evaluate ----
RUN=$WORK/run-$TRAIN_PRESET
rm -rf "$RUN" "$WORK/data-$TRAIN_PRESET"
run main_train "$BUDGET_TRAIN" "$PY" -m experiments.train --preset "$TRAIN_PRESET" --workdir "$RUN" \
    --dataset_dir "$WORK/data-$TRAIN_PRESET" --no_progress $TRAIN_FLAGS
mkdir -p "$OUT/main"
cp "$RUN"/metrics.jsonl "$RUN"/compile.jsonl "$RUN"/config.json "$OUT/main/" 2>/dev/null
cp "$WORK/data-$TRAIN_PRESET/manifest.json" "$OUT/main/data_manifest.json" 2>/dev/null
run main_evaluate "$BUDGET_EVAL" env PCMGN_COMPILE_LOG="$OUT/main/evaluate_compile.jsonl" \
    "$PY" -m experiments.evaluate --workdir "$RUN"
cp "$RUN"/eval/metrics.json "$OUT/main/eval_metrics.json" 2>/dev/null

# ---- (b) solver throughput against designs per call ----
run solver_throughput "$BUDGET_SOLVER" "$PY" -m benchmarks.solver_throughput $SOLVER_ARGS \
    --budget_s $((BUDGET_SOLVER - 10)) --json "$OUT/solver_throughput.json"

# ---- (c) gpu_check inside its budget ----
run gpu_check $((BUDGET_GPU_CHECK + 10)) "$PY" -m benchmarks.gpu_check $GPU_CHECK_ARGS \
    --budget_s "$BUDGET_GPU_CHECK" --json "$OUT/gpu_check.json"

# ---- (d) start-up: first training step, rollout and solver call, cold and warm cache ----
SU=$BUDGET_STARTUP; [ "$SU" -le 0 ] && SU=$(left)
run startup "$SU" "$PY" -m benchmarks.startup $STARTUP_ARGS --data "$WORK/data-$TRAIN_PRESET" \
    --budget_s $((SU > 15 ? SU - 10 : 5)) --json "$OUT/startup.json"

echo "== total $("$PY" -c "import time; print(round(time.time() - $START, 1))") s; figures in $OUT" \
  | tee "$OUT/total.log"
cat "$OUT/phases.tsv"
