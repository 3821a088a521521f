#!/usr/bin/env bash
# The device machine's side of a GPU session (docs/gpu_session.md): run there, from the repository root, with
# gpu_pack/ carried (scripts/gpu_carry.sh). Python 3.12 with a CUDA torch, no bpy, no network; the bpy-free
# packages import from the tree. Everything a call produces goes to $OUT (8 files of at most 16 MiB come back).
#   scripts/gpu_session.sh bench                       training and rendering speed (bench train, bench model)
#   scripts/gpu_session.sh profile                     bf16 against fp32 in training with cuDNN's attention
#                                                      kept out and (A/B) allowed, profiled (ATen calls,
#                                                      launches, syncs, allocations, device-busy ms per step;
#                                                      operator tables); FPS at 256 px eager and compiled
#                                                      (profiled); training with the networks compiled
#   scripts/gpu_session.sh fps                         FPS at 256 px (issue 13), profiled: every preset and kind
#                                                      eager; `fast` with the written-out attention, eager and
#                                                      compiled; CUDA graphs; Sem2NeRF (with a masked set)
#   scripts/gpu_session.sh objbatch                    a step's objects in shared forward passes (train.object_batch,
#                                                      ref_views_per) against one pass an object: steps/s,
#                                                      utilisation, launches
#   scripts/gpu_session.sh slice CONFIG FALLBACK BUDGET
#                                                      objbatch's check, a short objbatch timing at CONFIG's
#                                                      object_batch, then `train CONFIG` for what is left of
#                                                      BUDGET seconds (FALLBACK instead if the check fails)
#   scripts/gpu_session.sh synth                       `synthesize` on an orbit, eager, --compile (recompiles logged)
#                                                      and without empty-space skipping (SYNTH_VARIANTS; also
#                                                      nofoot: skipping without the footprint), seconds a view
#   scripts/gpu_session.sh score CHECKPOINT ...        held-out scores on the GPU (SCORE_SETS; gpu_eval_pack.sh)
#   scripts/gpu_session.sh mrvm_scale                  MRVM against none at a GPU budget, both arms side by side
#                                                      (FT_RECIPE=official: the official code's finetune, 2 x PRE at lr 1e-3)
#   scripts/gpu_session.sh train CONFIG SECONDS [CONFIG SECONDS ...]
#                                                      runs side by side, each stopped (SIGINT) after SECONDS;
#                                                      each run's last checkpoint's model in fp16, its log, and
#                                                      the run itself (<name>.run.tgz: config, metrics, last
#                                                      checkpoint with the optimizer; over 15 MiB, in parts
#                                                      <name>.run.tgz.partNN) for the next session: put it
#                                                      in gpu_pack/runs/ here and the next call resumes it
#                                                      exactly (GPU sessions are 15 minutes; a run spans several)
set -uo pipefail
export PYTHONPATH=${MRVM_CODE:-$PWD} MRVM_WEIGHTS_DIR=${MRVM_WEIGHTS_DIR:-$PWD/gpu_carry/weights} PYTHONUNBUFFERED=1
OUT=${OUT:-gpu_out}
mkdir -p "$OUT"
if [ ! -d gpu_carry ] && [ -f gpu_pack/carry.tgz ]; then mkdir -p gpu_carry && tar -xzf gpu_pack/carry.tgz -C gpu_carry; fi
PY=${PY:-python3}
# wheels the device lacks (gpu_carry.sh DEPTH=1: OpenEXR, for the depth maps the depth loss reads)
if ls gpu_carry/whl/*.whl > /dev/null 2>&1; then
  $PY -m pip install -q --no-index --no-deps --no-compile --target /tmp/site gpu_carry/whl/*.whl \
    && export PYTHONPATH=$PYTHONPATH:/tmp/site || echo "gpu_session: could not install gpu_carry/whl/*.whl" >&2
fi
# TF32 matrix products for fp32 runs (the training calls of session 18 ran with it; the benches without)
export TORCH_ALLOW_TF32_CUBLAS_OVERRIDE=${TORCH_ALLOW_TF32_CUBLAS_OVERRIDE:-1}

wait_logging_gpu() {  # wait for these processes while nvidia-smi logs utilisation and memory every 15 s
  nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader -l 15 > "$OUT/gpu_util.log" 2>&1 &
  local smi=$! p
  for p in "$@"; do wait "$p"; done
  kill $smi 2>/dev/null
}
what=${1:-}; shift || true
case "$what" in
  bench)
    nvidia-smi -L; $PY -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name(0))"
    timeout ${BENCH_TRAIN_S:-330} $PY -m blender_mrvm bench train --device cuda \
      --presets ${TRAIN_PRESETS:-fast,balanced,accurate,paper,gpnr:fast} --batches ${BATCHES:-2x256,8x1024,16x4096} \
      --precisions fp32,bf16 --steps ${STEPS:-10} --warmup 3 --data ${BENCH_DATA:-gpu_carry/data/shapenet13_all} --out "$OUT/train"
    timeout ${BENCH_MODEL_S:-150} $PY -m blender_mrvm bench model --device cuda \
      --presets ${MODEL_PRESETS:-fast,balanced,accurate,paper,gpnr:fast} --views 2 --sizes 128,256 \
      --precisions fp32,bf16 --chunk 65536 --ref-size 64 --repeats 5 --out "$OUT/model"
    # the CUDA paths of evaluation and synthesis, run for real with a shipped model (only their JSON comes back:
    # at most 8 files return, and session 18's call lost bench_train.csv to the rendered views)
    if [ -n "${EVAL_DATA:-}" ]; then
      timeout 90 $PY -m blender_mrvm eval --checkpoint shipped --data "$EVAL_DATA" --split train --n-inputs 2 --force \
        --max-targets 10 --no-lpips --device cuda --out /tmp/eval_cuda && cp /tmp/eval_cuda/eval.json "$OUT/eval_cuda.json"
      obj=$(ls -d "$EVAL_DATA"/*/*/ | head -n 1)
      timeout 60 $PY -m blender_mrvm synthesize --references "$obj" --views 3 15 --orbit 8 --device cuda \
        --out /tmp/synth_cuda && cp /tmp/synth_cuda/synthesis.json "$OUT/synth_cuda.json"
    fi
    ;;
  profile)
    # Session 20's one call (~9 min). Each step has its own limit and adds to $OUT/all.tgz as it ends (a call
    # cut short keeps what ran); the CSVs also come back as files.
    G=/tmp/gpu_profile; mkdir -p $G
    keep() { tar -czf "$OUT/all.tgz" -C $G . ; for f in $G/*/*.csv; do d=$(basename $(dirname $f)); cp $f "$OUT/$d.csv"; done; }
    nvidia-smi -L 2>/dev/null; $PY -c "import torch; print('torch', torch.__version__, 'cudnn', torch.backends.cudnn.version())"
    # 1. bf16 against fp32 with cuDNN's attention kept out (models/nerformer.configure_attention), profiled
    timeout ${PROFILE_S:-200} $PY -m blender_mrvm bench train --device ${DEVICE:-cuda} \
      --presets ${TRAIN_PRESETS:-balanced,accurate} --batches ${BATCHES:-8x1024,16x4096} --precisions fp32,bf16 \
      --steps ${STEPS:-5} --warmup 3 --profile ${PROFILE_STEPS:-2} --resolution ${RESOLUTION:-64} \
      ${BENCH_DATA:+--data $BENCH_DATA} --out $G/train; keep
    # 2. the same in bf16 with cuDNN's attention allowed (what session 18 measured): the A/B of the cause
    MRVM_CUDNN_ATTENTION=1 timeout ${CUDNN_S:-90} $PY -m blender_mrvm bench train --device ${DEVICE:-cuda} \
      --presets ${TRAIN_PRESETS:-balanced,accurate} --batches 8x1024 --precisions bf16 \
      --steps ${STEPS:-5} --warmup 3 --profile ${PROFILE_STEPS:-2} --resolution ${RESOLUTION:-64} \
      ${BENCH_DATA:+--data $BENCH_DATA} --out $G/train_cudnn; keep
    # 3. frames per second at 256 px (issue 13: 30 for fast), eager then compiled, each with a profiled render
    timeout ${MODEL_S:-60} $PY -m blender_mrvm bench model --device ${DEVICE:-cuda} --presets ${MODEL_PRESETS:-fast,balanced} \
      --views 2 --sizes ${SIZES:-256} --precisions fp32,bf16 --chunk 65536 --ref-size 64 --repeats 5 --profile \
      --out $G/model; keep
    timeout ${COMPILE_S:-150} $PY -m blender_mrvm bench model --device ${DEVICE:-cuda} --presets fast \
      --views 2 --sizes ${SIZES:-256} --precisions fp32,bf16 --chunk 65536 --ref-size 64 --repeats 5 --compile \
      --profile --out $G/model_compiled; keep
    # 4. training with the networks compiled, while time is left
    timeout ${TRAIN_COMPILE_S:-120} $PY -m blender_mrvm bench train --device ${DEVICE:-cuda} --presets accurate \
      --batches 8x1024 --precisions bf16,fp32 --steps ${STEPS:-5} --warmup 3 --compile --resolution ${RESOLUTION:-64} \
      ${BENCH_DATA:+--data $BENCH_DATA} --out $G/train_compiled; keep
    ;;
  fps)
    # frames per second at 256 px (issue 13: 30 for fast), each step with one profiled render: every preset and
    # kind eager (fp32, bf16); `fast` fp32 eager and compiled with the fused attention kernel (MRVM_SHORT_ATTENTION=0)
    # against the default on a GPU since session 23 (attention over up to 16 tokens written out); CUDA graphs
    # (reduce-overhead) on the compiled networks
    G=/tmp/gpu_fps; mkdir -p $G
    keep() { tar -czf "$OUT/fps.tgz" -C $G . ; }  # one file (at most 8 come back), rewritten after every step
    nvidia-smi -L 2>/dev/null; $PY -c "import torch; print('torch', torch.__version__, 'cudnn', torch.backends.cudnn.version())"
    # one bench model step (each its own inductor cache: a compilation killed by its limit leaves a partial file
    # that the next step would load)
    model() { out=$1; shift; TORCHINDUCTOR_CACHE_DIR=/tmp/inductor_$out timeout ${STEP_S:-150} $PY -m blender_mrvm \
      bench model --device ${DEVICE:-cuda} --views 2 --sizes ${SIZES:-256} --chunk 65536 --ref-size 64 \
      --repeats ${REPEATS:-5} --out $G/$out "$@"; keep; }
    bm() { out=$1; shift; model "$out" --profile "$@"; }
    # the same machine's baseline, when the tree before a change came along (git archive <rev> blender_mrvm into
    # gpu_old/, carried): `python -m` imports from the working directory, so it runs from there
    old() { (cd gpu_old && PYTHONPATH=$PWD model "$@"); }
    [ -d gpu_old/blender_mrvm ] && old old_eager --presets fast,balanced --precisions fp32
    bm eager --presets ${MODEL_PRESETS:-fast,balanced,accurate,gpnr:fast} --precisions fp32,bf16
    MRVM_SHORT_ATTENTION=0 bm eager_fused --presets fast --precisions fp32
    bm compiled --presets fast --precisions fp32 --compile
    MRVM_SHORT_ATTENTION=0 bm compiled_fused --presets fast --precisions fp32 --compile
    bm graphs --presets fast --precisions fp32 --compile-mode reduce-overhead
    # Sem2NeRF, the third kind, when a masked test set came along (SPLITS=test MAX_OBJECTS=2 scripts/gpu_carry.sh;
    # skipped when the test list's first object was not carried, as in a pack of train splits):
    # seconds per 256 px view (fps = 1 / seconds_per_view) at its samples and precisions, mask encoded once
    S2N_DATA=${S2N_DATA:-gpu_carry/data/shapenet13_all}
    if [ -f "$S2N_DATA/splits/test.lst" ] && [ -d "$S2N_DATA/$(head -n 1 "$S2N_DATA/splits/test.lst")" ]; then
      timeout ${S2N_S:-90} $PY -m blender_mrvm bench tradeoff --device ${DEVICE:-cuda} --data "$S2N_DATA" \
        --checkpoints shipped:sem2nerf --axes ${S2N_AXES:-base,samples,precision} --objects 2 --targets 2 --size 256 \
        --repeats 5 --no-lpips --out $G/sem2nerf; keep
    fi
    ;;
  objbatch)
    # issue 11: train.object_batch (objects of a step with the same reference count in one forward pass; with
    # train.ref_views_per "step" one count a step, so one pass) against one pass per object, with the LPIPS patch loss
    # as the recipes train (needs all of VGG16: gpu_carry.sh FULL_VGG=1); `fast` and `accurate`, one CSV each
    nvidia-smi -L
    # first whether the batched path is right on this device: losses and gradients against one pass per object
    # (OBJBATCH_CHECK=0: already checked, by `slice`)
    [ "${OBJBATCH_CHECK:-1}" = 0 ] || \
      $PY scripts/check_object_batch.py --device ${BENCH_DEVICE:-cuda} --amp bf16 2>&1 | tee "$OUT/objbatch_check.txt"
    for pb in ${OBJBATCH_RUNS:-fast:32x256 accurate:32x1024}; do
      timeout ${BENCH_TRAIN_S:-170} $PY -m blender_mrvm bench train --device ${BENCH_DEVICE:-cuda} --presets "${pb%%:*}" \
        --batches "${pb#*:}" --object-batches ${OBJECT_BATCHES:-1,16} --ref-views-per ${REF_VIEWS_PER:-object,step} \
        --precisions ${PRECISIONS:-bf16} --lpips-weight ${LPIPS_WEIGHT:-0.5} --steps ${STEPS:-6} --warmup 2 --profile 1 \
        --data ${BENCH_DATA:-gpu_carry/data/shapenet13_all} --out "$OUT/objbatch_${pb%%:*}"
    done
    ;;
  slice)
    # the next GPU session's training call in one (session 34: a start, this call and a scoring call fit 15 minutes,
    # where objbatch + train + score did not): the batched path checked on the device; if right, timed against one
    # pass an object on the same machine (SLICE_BENCH_RUNS, a few steps each) and CONFIG trained for what is left of
    # BUDGET seconds; if the check fails, FALLBACK (the same slice one object at a time) trains instead
    [ $# -eq 3 ] || { echo "usage: $0 slice CONFIG FALLBACK BUDGET_SECONDS" >&2; exit 2; }
    cfg=$1; fallback=$2; budget=$3; t0=$SECONDS
    # train CONFIG for SECONDS (WHY noted), with the tree in gpu_old/ if CODE is "old" and it came along: a fallback
    # may be needed for a fault in the code every object's loss now goes through (training/trainer._group_terms), so
    # it trains with the last tree that trained on a GPU (docs/gpu_session.md); python -P keeps the working
    # directory's tree off sys.path
    slice_train() {  # CONFIG SECONDS CODE WHY
      local how=""; [ "$3" = old ] && [ -d gpu_old/blender_mrvm ] && how=" with the code in gpu_old/"
      echo "slice: training $1$how for $2 s ($4)" | tee -a "$OUT/objbatch_check.txt"
      if [ -n "$how" ]; then MRVM_CODE=$PWD/gpu_old PY="$PY -P" bash "$0" train "$1" "$2"
      else bash "$0" train "$1" "$2"; fi
    }
    min_s=${SLICE_MIN_S:-60}
    left() { echo $((budget - (SECONDS - t0))); }
    remaining() { local l; l=$(left); echo $((l > min_s ? l : min_s)); }
    if $PY scripts/check_object_batch.py --device ${BENCH_DEVICE:-cuda} --amp bf16 > "$OUT/objbatch_check.txt" 2>&1; then
      ob=$($PY -c "import json, sys; print(json.load(open(sys.argv[1]))['train'].get('object_batch', 1))" "$cfg")
      [ "$ob" -gt 1 ] && OBJBATCH_CHECK=0 OBJECT_BATCHES=1,$ob REF_VIEWS_PER=${SLICE_REF_VIEWS_PER:-object,step} \
        STEPS=${SLICE_BENCH_STEPS:-3} BENCH_TRAIN_S=${SLICE_BENCH_S:-180} OBJBATCH_RUNS="${SLICE_BENCH_RUNS:-accurate:32x1024}" \
        bash "$0" objbatch
      slice_train "$cfg" "$(remaining)" new "check passed"
      # a batched slice that saved no step (out of memory at its first step, say) leaves the rest of the budget to
      # the fallback
      if ! ls -d "runs/$(basename "$cfg" .json)"/checkpoints/step_* > /dev/null 2>&1 \
         && [ "$(left)" -ge "$min_s" ]; then
        slice_train "$fallback" "$(remaining)" old "$cfg saved no step: $(basename "$cfg" .json).log"
      fi
    else
      slice_train "$fallback" "$(remaining)" old "check FAILED"
    fi
    ;;
  synth)
    # `synthesize` itself on an orbit (issue 13: `--compile` was timed only through `bench model`): each shipped
    # model eager and compiled, seconds per view from synthesis.json (the first view of a compiled run pays the
    # compilation); one JSON per run, <model>_<eager|compiled>.json, also gathered into synth.tgz after each run
    # (variants: eager, compiled, and eager without empty-space skipping ("noskip": what the hull costs or saves
    # on the device); compiled runs log torch's recompilations and graph breaks into synth.tgz's logs/)
    # ("nofoot": skipping without the view's footprint, every box ray marched: the footprint's splat and distance
    # transform run on the host; measurement only, by replacing hull.footprint with "every pixel" in that process;
    # the images must not change, tests/test_gpu_session_script.py. Session 29 timed it faster on an H100, so since
    # then a GPU never makes the footprint (hull.footprint_pays) and there `nofoot` is the same as `eager`)
    obj=$(ls -d ${SYNTH_DATA:-gpu_carry/data/shapenet13_all}/*/*/ | head -n 1)
    tmp=${SYNTH_TMP:-/tmp}
    mkdir -p $tmp/synth_logs
    nofoot='import sys, torch, runpy, blender_mrvm.models.hull as h
def every_pixel(hull, intr, c2w):
    print(f"nofoot: every pixel of a {intr.width}x{intr.height} view marched", file=sys.stderr)
    return torch.ones(int(intr.height) * int(intr.width), dtype=torch.bool)
h.footprint = every_pixel
runpy.run_module("blender_mrvm", run_name="__main__")'
    for m in ${SYNTH_MODELS:-nerformer_mrvm mrvm_quality}; do
      for c in ${SYNTH_VARIANTS:-eager compiled noskip}; do
        flag=; logs=; launch=(-m blender_mrvm)  # (TORCH_LOGS set but empty breaks torch's logging)
        [ "$c" = compiled ] && flag=--compile && logs=recompiles,graph_breaks
        [ "$c" = noskip ] && flag="--skip-empty off"
        [ "$c" = nofoot ] && launch=(-c "$nofoot")
        env ${logs:+TORCH_LOGS=$logs} TORCHINDUCTOR_CACHE_DIR=/tmp/inductor_synth_$m timeout ${STEP_S:-120} $PY "${launch[@]}" \
          synthesize --references "$obj" --views ${SYNTH_VIEWS:-3 15} --orbit ${ORBIT:-24} --orbit-size ${SIZE:-256} \
          --checkpoint shipped:$m --device ${DEVICE:-cuda} $flag --out $tmp/synth_${m}_$c --force \
          2> >(grep -v "^synthesize: " > $tmp/synth_logs/${m}_$c.log) \
          && cp $tmp/synth_${m}_$c/synthesis.json "$OUT/${m}_$c.json"
        tar -czf "$OUT/synth.tgz" -C "$OUT" --exclude synth.tgz . -C $tmp synth_logs
      done
    done
    $PY - "$OUT" <<'EOF2'
import json, statistics, sys
from pathlib import Path
runs = sorted(Path(sys.argv[1]).glob("*_*.json"))
if not runs:
    sys.exit("synth: no run finished (their errors are in synth.tgz's synth_logs/)")
for f in runs:
    d = json.loads(f.read_text()); s = [t["seconds"] for t in d["targets"]]
    print(f"{f.stem}: {len(s)} views of {d['targets'][0]['width']} px, first {s[0]:.3f} s, "
          f"median of the rest {statistics.median(s[1:]):.4f} s ({1 / statistics.median(s[1:]):.1f} FPS), total {d['seconds']:.1f} s")
EOF2
    ;;
  score)
    # CHECKPOINT ...: each checkpoint scored on each SCORE_SETS entry ("SET:SPLIT:TARGETS[:PER_CATEGORY]", sets
    # under gpu_eval/data from scripts/gpu_eval_pack.sh, carried as ["gpu_eval"]), SCORE_JOBS evaluations at a
    # time on the one GPU, 2 references, LPIPS with the carried fp16 VGG16. Back: score.tgz (every eval.json and
    # log; SCORE_S bounds them all, so it is written before the call's limit); pair them here
    # (training.evaluate.compare_reports). Session 31: two `quality` files on 7 sets, ~2 000 views.
    # On the CPU here (no device time left): DEVICE=cpu SCORE_JOBS=2 SCORE_THREADS=1 and a SCORE_S of hours
    # (two 1-thread jobs on the 2 cores; 2 threads each would oversubscribe them)
    [ -d gpu_eval/data ] || tar -xzf gpu_eval/eval.tgz -C gpu_eval || exit 1
    export MRVM_WEIGHTS_DIR=$PWD/gpu_eval/weights
    tmp=${SCORE_TMP:-/tmp/score}; rm -rf "$tmp"; mkdir -p "$tmp/logs"
    jobs_=()
    for spec in ${SCORE_SETS:?name the sets}; do
      IFS=: read -r set split tg k <<< "$spec"
      for ck in "$@"; do
        jobs_+=("$ck|$set|$split|$tg|$k")
      done
    done
    deadline=$((SECONDS + ${SCORE_S:-240}))  # every evaluation ends by then, so score.tgz is always written
    run_one() {
      IFS='|' read -r ck set split tg k <<< "$1"
      local tag; tag=$(basename "${ck%.safetensors}")__${set}_$split
      timeout $((deadline - SECONDS)) $PY -m blender_mrvm eval --checkpoint "$ck" --data "gpu_eval/data/$set" --split "$split" \
        --n-inputs 2 --max-targets "$tg" ${k:+--max-objects-per-category $k} --device ${DEVICE:-cuda} --threads ${SCORE_THREADS:-2} --force \
        --out "$tmp/$tag" > "$tmp/logs/$tag.log" 2>&1
      local rc=$?; echo "$tag: rc $rc"; [ $rc = 0 ] || tail -n 2 "$tmp/logs/$tag.log"
    }
    for j in "${jobs_[@]}"; do
      while [ "$(jobs -rp | wc -l)" -ge "${SCORE_JOBS:-6}" ]; do sleep 1; done
      [ $((deadline - SECONDS)) -gt 5 ] || { echo "score: out of time before ${j%%|*} on ${j#*|}"; continue; }
      run_one "$j" &
    done
    wait
    (cd "$tmp" && find . -name eval.json -o -name '*.log' | tar -czf "$OUT/score.tgz" -T -)
    n=$(ls "$tmp"/*/eval.json 2>/dev/null | wc -l)
    echo "score: $n of ${#jobs_[@]} evaluations finished"; [ "$n" = ${#jobs_[@]} ]
    ;;
  train)
    # runs carried back from an earlier session (gpu_pack/runs/<name>.run.tgz) resume where they stopped
    mkdir -p runs
    # (a run over the 16 MiB a returned file may have came back in parts: <name>.run.tgz.part00, part01, ...)
    for t in gpu_pack/runs/*.run.tgz gpu_pack/runs/*.run.tgz.part00; do
      [ -f "$t" ] || continue
      n=$(basename "${t%.part00}" .run.tgz); mkdir -p "runs/$n" && cat "${t%.part00}"* | tar -xzf - -C "runs/$n" \
        && echo "runs/$n: resuming from $(ls runs/$n/checkpoints)"
    done
    pids=()
    while [ $# -ge 2 ]; do
      cfg=$1; secs=$2; shift 2
      name=$(basename "$cfg" .json)
      timeout -s INT "$secs" $PY -m blender_mrvm train --config "$cfg" --out "runs/$name" > "$OUT/$name.log" 2>&1 &
      pids+=($!)
    done
    wait_logging_gpu "${pids[@]}"
    for d in runs/*/; do
      name=$(basename "$d")
      last=$(ls -d "$d"checkpoints/step_* 2>/dev/null | sort | tail -n 1)
      if [ -n "$last" ]; then
        # the run, resumable. At most 16 MiB come back per file, and `accurate`'s model with its AdamW state is
        # ~26 MB packed (session 24 lost one that way), so a larger archive comes back in parts (RUN_PART_BYTES)
        # (RUN_CHECKPOINT=0: config and metrics alone, for runs side by side that would return more than 8 files
        # and an `accurate` run, whose optimizer does not fit a carry beside the data anyway)
        ck="checkpoints/$(basename "$last")"; [ "${RUN_CHECKPOINT:-1}" = 0 ] && ck=
        tar -czf "$OUT/$name.run.tgz" -C "$d" config.json metrics.jsonl $ck
        part=${RUN_PART_BYTES:-15728640}
        if [ "$(stat -c %s "$OUT/$name.run.tgz")" -gt "$part" ]; then
          split -d -a 2 -b "$part" "$OUT/$name.run.tgz" "$OUT/$name.run.tgz.part" && rm "$OUT/$name.run.tgz"
          echo "$name.run.tgz came back in $(ls "$OUT/$name.run.tgz.part"* | wc -l) parts (cat them in order)" >&2
        fi
      fi
      $PY - "$d" "$OUT/$name.safetensors" <<'EOF'
import sys
from pathlib import Path
from blender_mrvm.training.checkpoint import half_copy
steps = sorted(Path(sys.argv[1]).glob("checkpoints/step_*/model.safetensors"))
if not steps:
    sys.exit(f"{sys.argv[1]}: no checkpoint")
print(f"{half_copy(steps[-1], Path(sys.argv[2]))}: {steps[-1]}")
EOF
    done
    ;;
  mrvm_scale)
    # Issue 11: MRVM against the identical model without it at a GPU budget, beside the CPU's three budgets
    # (RECIPE.md "MRVM against the identical model at three training budgets": the `fast` preset, the paper's
    # two runs). Both arms side by side, each a pretraining run of PRE steps then a finetuning run of PRE/3 from
    # it, OBJ x RAYS rays a step (default 300 + 100 steps of 16 x 4096: 26 M rays, 8x the CPU's largest budget in
    # rays, 400 updates against its 12 000; ~7.5 minutes on an H100; session 28's 180 + 60 kept a 200-step warmup).
    # Steps, not time, are the budget: each run's timeout is only a guard, and the summary says if one cut a run
    # short (then the arms are not comparable; the guards allow 1.5 s a step, session 28 ran ~1.05 side by side).
    # Back: scale_<arm>.safetensors (fp16), scale_<arm>.log,
    # scale_runs.tgz (configs and metrics), gpu_util.log; scored on the CPU (docs/gpu_session.md).
    # FT_RECIPE=official: the official code's finetune instead, 2 x PRE steps at a constant lr 1e-3 with no warm-up
    # (session 44 on the CPU: it takes MRVM's PSNR cost away; RECIPE.md "The official finetune").
    PRE=${PRE:-300}; FT=$((PRE / 3)); [ "$FT" -ge 1 ] || FT=1
    case "${FT_RECIPE:-}" in
      official) FT=$((2 * PRE)) ;;
      "") ;;
      *) echo "error: FT_RECIPE must be official or unset, not $FT_RECIPE" >&2; exit 2 ;;
    esac
    mkdir -p runs /tmp/mrvm_scale
    pids=()
    for arm in mrvm base; do
      $PY - "$arm" "/tmp/mrvm_scale/$arm.json" "$PRE" <<'EOF'
import json, os, sys
from blender_mrvm.training.config import TrainConfig
arm, out, pre = sys.argv[1], sys.argv[2], int(sys.argv[3])
c = json.load(open(f"blender_mrvm/assets/checkpoints/ablation/budget_unseen_{arm}.json"))
# the warmup in proportion to the run, as the CPU study's smallest budget had it (200 of 1000 steps): session 28's
# first GPU run (PRE 180) kept the default 200 steps and never left its warmup, so the learning rate never peaked
warmup = int(os.environ.get("WARMUP", min(c["train"].get("lr_warmup", TrainConfig.lr_warmup), max(1, pre // 5))))
c["train"].update(lr_warmup=warmup, data=os.environ.get("MRVM_DATA", "gpu_carry/data/shapenet13_all"), seed=int(os.environ.get("SEED", "0")),
                  objects_per_step=int(os.environ.get("OBJ", "16")), rays_per_object=int(os.environ.get("RAYS", "4096")),
                  device=os.environ.get("DEVICE", "cuda"), amp=os.environ.get("AMP", "none"), threads=0,
                  log_every=5, ckpt_every=1000000, keep_checkpoints=1)
json.dump(c, open(out, "w"), indent=1)
if os.environ.get("FT_RECIPE") == "official":  # the finetune's own settings win over the fine-tuning policy
    from blender_mrvm.training.config import MRVM_OFFICIAL_FINETUNE
    c["train"].update(MRVM_OFFICIAL_FINETUNE)
json.dump(c, open(out.replace(".json", "_ft.json"), "w"), indent=1)
EOF
      ( timeout -s INT ${PRE_S:-$((PRE * 3 / 2 + 60))} $PY -m blender_mrvm train --config /tmp/mrvm_scale/$arm.json --iterations $PRE \
          --out runs/scale_${arm}_pre --no-resume --force
        timeout -s INT ${FT_S:-$((FT * 3 / 2 + 60))} $PY -m blender_mrvm train --config /tmp/mrvm_scale/${arm}_ft.json \
          --init runs/scale_${arm}_pre --iterations $FT --out runs/scale_$arm --no-resume --force ) > "$OUT/scale_$arm.log" 2>&1 &
      pids+=($!)
    done
    wait_logging_gpu "${pids[@]}"
    tar -czf "$OUT/scale_runs.tgz" -C runs $(cd runs && ls scale_*/config.json scale_*/metrics.jsonl 2>/dev/null)
    for arm in mrvm base; do
      $PY - "$arm" "$OUT/scale_$arm.safetensors" "$PRE" "$FT" <<'EOF'
import sys
from pathlib import Path
from blender_mrvm.training.checkpoint import half_copy
arm, out, pre, ft = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
for run, want in ((f"runs/scale_{arm}_pre", pre), (f"runs/scale_{arm}", ft)):
    steps = sorted(Path(run).glob("checkpoints/step_*/model.safetensors"))
    got = int(steps[-1].parent.name.split("_")[1]) if steps else 0
    print(f"{run}: step {got} of {want}" + ("" if got == want else "  CUT SHORT: the arms are not comparable"))
if steps:
    half_copy(steps[-1], out)
EOF
    done
    ;;
  *) echo "usage: $0 bench | profile | fps | objbatch | slice CONFIG FALLBACK BUDGET | synth | score ... | mrvm_scale | train CONFIG SECONDS [...]" >&2; exit 2 ;;
esac
