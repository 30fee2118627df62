#!/usr/bin/env bash
# gpu-train-check.sh: does sartor's training run on burn's wgpu backend on a real GPU, and how
# fast is it against the flex CPU backend on the same machine?
#
# Run from the repository root, with a prebuilt xtask that has the `wgpu` feature (no cargo
# needed there):
#
#   CARGO_TARGET_DIR=target-wgpu cargo build --release -p xtask --features wgpu
#   mkdir -p .gpu && strip -o /tmp/xtask target-wgpu/release/xtask && gzip -9c /tmp/xtask >.gpu/xtask.gz
#   OUT=/tmp/gpucheck bench/gpu-train-check.sh
#
# What it does, all under $WORK (default /tmp/gpu-train-check), nothing written into the tree:
#   0. unpacks the Vulkan/GL loaders of .gl/*.deb into / when .gl/ is there (a bare CUDA image
#      has none; SKIP_GL_UNPACK=1 skips it) and logs nvidia-smi and the Vulkan ICD files;
#   1. `simulate` + `dataset` of configs/tiny.json and of "gpucheck", a config written below:
#      the 4,210-triangle T-shirt (2,168 vertices) of configs/default.json on 4 training
#      shapes x 6 CMU clips (12 sequences of 90 frames, 974 training frames), with default.json's
#      networks (fit MLP 20, GRU 256, PCA-64 output, 90-frame windows, batch 8) and fewer epochs;
#   2. `train --backend wgpu` on tiny (the functional check; first with
#      CUBECL_WGPU_DEFAULT_DEVICE=DiscreteGpu(0) so that no software adapter can stand in for
#      the GPU, then, if that fails, with the default adapter choice), then `train --backend
#      flex` on tiny;
#   3. gpucheck per model (`--models wrinkle`, `fit`, `linear`), flex first, then wgpu, each in
#      its own runs folder over copies of one simulation, each under a SIGINT timeout (training
#      then checkpoints and still writes train.json, with `interrupted: true`); the wgpu runs
#      get what is left of BUDGET_S (default 300 s for the whole script), and run only when the
#      tiny check found an NVIDIA adapter (not on a software one such as llvmpipe);
#   while wgpu trains, nvidia-smi samples the GPU's utilisation and memory every second.
#
# Into $OUT (at most 8 files): log.txt (everything, written as it goes), summary.txt (one line
# per step: name, exit status, seconds), gpu-samples.csv, train-{tiny,gpucheck}-{wgpu,flex}.json
# (each train.json: per model wall time, frames/s, best validation error, loss curves).
# A failing step is logged and the script goes on; it exits 0 unless the setup itself fails.
# TIMEOUT_SCALE=N multiplies every step's timeout (for a slow machine: 2 cores take about 8x).
set -u -o pipefail

OUT=${OUT:?set OUT to the folder that receives the results}
XTASK=${XTASK:-}
WORK=${WORK:-/tmp/gpu-train-check}
BUDGET_S=${BUDGET_S:-300}
TIMEOUT_SCALE=${TIMEOUT_SCALE:-1}
START_NS=$(date +%s%N)
mkdir -p "$OUT"
LOG=$OUT/log.txt
SUMMARY=$OUT/summary.txt
: >"$LOG"
: >"$SUMMARY"

log() { echo "[$(elapsed)s] $*" | tee -a "$LOG"; }
elapsed() { echo $((($(date +%s%N) - START_NS) / 1000000000)); }

# step NAME TIMEOUT_S CMD...: runs CMD with its output appended to the log, under a SIGINT
# timeout (KILL 20 s later); records the exit status and the wall time in summary.txt.
step() {
    local name=$1 limit=$(($2 * TIMEOUT_SCALE))
    shift 2
    log "=== $name (timeout ${limit}s): $*"
    local t0 t1 rc
    t0=$(date +%s%N)
    timeout -s INT -k 20 "$limit" "$@" 2>&1 | tee -a "$LOG"
    rc=$?
    t1=$(date +%s%N)
    local ms=$(((t1 - t0) / 1000000))
    printf '%-28s rc=%-4s %d.%03d s\n' "$name" "$rc" $((ms / 1000)) $((ms % 1000)) | tee -a "$SUMMARY" "$LOG"
    return $rc
}

# --- 0. loaders, machine --------------------------------------------------------------------
if [ -z "${SKIP_GL_UNPACK:-}" ] && ls .gl/*.deb >/dev/null 2>&1; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
if [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
if [ -f /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ]; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
# The xtask binary: $XTASK, else .gpu/xtask, else .gpu/xtask.gz unpacked into /tmp (stripped, it
# is 65 MB, over what a device call carries; gzip -9 makes it 19).
if [ -z "$XTASK" ]; then
    if [ -x .gpu/xtask ]; then
        XTASK=.gpu/xtask
    elif [ -f .gpu/xtask.gz ]; then
        XTASK=/tmp/sartor-xtask-wgpu
        gzip -dc .gpu/xtask.gz >"$XTASK" && chmod +x "$XTASK"
    fi
fi
{
    echo "=== machine: $(uname -a)"
    echo "nproc: $(nproc); $(grep -m1 'model name' /proc/cpuinfo)"
    echo "VK_DRIVER_FILES=${VK_DRIVER_FILES:-}"
    ls -l /usr/local/nvidia/share/vulkan/icd.d/ /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>&1
    ldconfig -p | grep -E 'libvulkan|libEGL|libGLX_nvidia|libnvidia-glcore' 2>&1
    nvidia-smi 2>&1
    echo "=== xtask: $XTASK"
    ls -l "$XTASK" 2>&1
    ldd "$XTASK" 2>&1
} >>"$LOG" 2>&1
[ -x "$XTASK" ] || { log "no executable $XTASK"; exit 2; }
[ -f configs/tiny.json ] || { log "run from the repository root"; exit 2; }

# --- 1. simulations and datasets ------------------------------------------------------------
rm -rf "$WORK"
mkdir -p "$WORK/flex" "$WORK/cfg"
cat >"$WORK/cfg/gpucheck.json" <<'EOF'
{
  "name": "gpucheck",
  "garment": "datasets/garments/tshirt-4210",
  "shapes": {
    "train": [
      { "id": "s00", "betas": [0, 0, 0, 0] },
      { "id": "s01", "betas": [-2, 0, 0, 0] },
      { "id": "s02", "betas": [2, 0, 0, 0] },
      { "id": "s03", "betas": [0, 2, 0, 0] }
    ],
    "validation": [{ "id": "v00", "betas": [0.5, -1, 1, -0.5] }],
    "held_out": [{ "id": "h00", "betas": [1.5, 0, 0, 0] }]
  },
  "motions": {
    "train": ["cmu/01_07@560+90", "cmu/02_04@16+90", "cmu/05_06@66+90",
              "cmu/06_01@17+90", "cmu/07_04@12+90", "cmu/09_01"],
    "validation": ["cmu/07_02@12+60"],
    "held_out": ["cmu/02_02@8+60"],
    "held_out_shapes": ["cmu/02_02@8+60"],
    "max_frames": 90,
    "shapes_per_motion": 2
  },
  "simulation": {
    "blend_frames": 10,
    "rest_frames": 10,
    "sim": { "linear_solver": { "ConjugateGradient": { "max_iterations": 1000, "relative_tolerance": 1e-05 } } },
    "arm_clearance": { "upper_arm_clearance_m": 0.005 },
    "max_step_per_edge_s_per_m": 0.066
  },
  "dataset": { "pca": { "components": 64, "max_frames": 6000, "seed": 2019 } },
  "training": {
    "fit": { "epochs": 500, "batch_size": 17, "learning_rate": 0.003 },
    "wrinkle": { "epochs": 400, "batch_size": 8, "learning_rate": 0.002, "final_learning_rate": 1e-05 },
    "linear": { "epochs": 40, "batch_size": 256, "learning_rate": 0.001 },
    "fit_hidden": 20,
    "gru_hidden": 256,
    "dropout": 0.2,
    "wrinkle_dropout": 0.5,
    "pca_components": 64,
    "window_frames": 90,
    "seed": 2019
  }
}
EOF
TINY=configs/tiny.json
BIG=$WORK/cfg/gpucheck.json

step simulate-tiny 60 "$XTASK" simulate --config "$TINY" --runs-dir "$WORK/flex"
step dataset-tiny 30 "$XTASK" dataset --config "$TINY" --runs-dir "$WORK/flex"
step simulate-gpucheck 150 "$XTASK" simulate --config "$BIG" --runs-dir "$WORK/flex"
step dataset-gpucheck 60 "$XTASK" dataset --config "$BIG" --runs-dir "$WORK/flex"
# The wgpu runs train on copies of the same simulations and datasets.
cp -a "$WORK/flex" "$WORK/wgpu"

# --- 2. tiny: the functional check -----------------------------------------------------------
SAMPLER=
sample_gpu() {
    if command -v nvidia-smi >/dev/null 2>&1; then
        echo "# $1" >>"$OUT/gpu-samples.csv"
        nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used,power.draw \
            --format=csv,noheader -l 1 >>"$OUT/gpu-samples.csv" 2>&1 &
        SAMPLER=$!
    fi
}
stop_sampling() {
    if [ -n "$SAMPLER" ]; then
        kill "$SAMPLER" 2>/dev/null
        wait "$SAMPLER" 2>/dev/null
        SAMPLER=
    fi
}
trap stop_sampling EXIT

WGPU_OK=
sample_gpu "tiny wgpu, DiscreteGpu(0)"
LOG_LINES=$(wc -l <"$LOG")
CUBECL_WGPU_DEFAULT_DEVICE='DiscreteGpu(0)' step train-tiny-wgpu 90 \
    "$XTASK" train --config "$TINY" --runs-dir "$WORK/wgpu" --backend wgpu
rc=$?
if [ $rc -eq 0 ] || [ $rc -eq 124 ] || [ $rc -eq 137 ]; then
    # Done, or ran out of time on the GPU (slow, not broken): no second try.
    WGPU_OK=discrete
else
    stop_sampling
    log "wgpu on DiscreteGpu(0) failed; again with the default adapter choice"
    rm -rf "$WORK/wgpu/tiny/train"
    sample_gpu "tiny wgpu, default adapter"
    if step train-tiny-wgpu-default 60 \
        "$XTASK" train --config "$TINY" --runs-dir "$WORK/wgpu" --backend wgpu; then
        WGPU_OK=default
        # The failed attempt's error lists the adapters wgpu found: a software one (llvmpipe,
        # device_type Cpu) is no GPU, and gpucheck is not worth training on it.
        if ! tail -n +"$((LOG_LINES + 1))" "$LOG" | grep -qiE 'AdapterInfo \{ name: [^,]*nvidia'; then
            WGPU_OK=software
            log "no NVIDIA adapter among those wgpu found: gpucheck is not trained on wgpu"
        fi
    fi
fi
stop_sampling
cp "$WORK/wgpu/tiny/train/train.json" "$OUT/train-tiny-wgpu.json" 2>/dev/null
step train-tiny-flex 90 "$XTASK" train --config "$TINY" --runs-dir "$WORK/flex" --backend flex
cp "$WORK/flex/tiny/train/train.json" "$OUT/train-tiny-flex.json" 2>/dev/null

# --- 3. gpucheck: the measurement ------------------------------------------------------------
for m in wrinkle fit linear; do
    case $m in wrinkle) t=150 ;; fit) t=90 ;; linear) t=60 ;; esac
    step "train-gpucheck-flex-$m" "$t" \
        "$XTASK" train --config "$BIG" --runs-dir "$WORK/flex" --backend flex --models "$m"
done
cp "$WORK/flex/gpucheck/train/train.json" "$OUT/train-gpucheck-flex.json" 2>/dev/null

if [ "$WGPU_OK" = discrete ] || [ "$WGPU_OK" = default ]; then
    [ "$WGPU_OK" = discrete ] && export CUBECL_WGPU_DEFAULT_DEVICE='DiscreteGpu(0)'
    sample_gpu "gpucheck wgpu ($WGPU_OK adapter)"
    # The GRU first: it is most of training's cost (61 of 76 s in the default run on flex).
    for m in wrinkle fit linear; do
        left=$((BUDGET_S - $(elapsed) - 10))
        case $m in wrinkle) t=$((left * 55 / 100)) ;; fit) t=$((left * 2 / 3)) ;; linear) t=$left ;; esac
        [ "$t" -gt 150 ] && t=150
        if [ "$t" -lt 10 ]; then
            log "train-gpucheck-wgpu-$m: skipped, ${left}s of BUDGET_S=${BUDGET_S}s left"
            echo "train-gpucheck-wgpu-$m skipped (budget)" >>"$SUMMARY"
            continue
        fi
        step "train-gpucheck-wgpu-$m" "$t" \
            "$XTASK" train --config "$BIG" --runs-dir "$WORK/wgpu" --backend wgpu --models "$m"
    done
    stop_sampling
    cp "$WORK/wgpu/gpucheck/train/train.json" "$OUT/train-gpucheck-wgpu.json" 2>/dev/null
else
    log "wgpu: ${WGPU_OK:-failed} on tiny: gpucheck not trained on wgpu"
fi

# --- the numbers, in the log -----------------------------------------------------------------
{
    echo "=== summary (BUDGET_S=$BUDGET_S, wgpu adapter: ${WGPU_OK:-none})"
    cat "$SUMMARY"
    for f in "$OUT"/train-*.json; do
        [ -f "$f" ] || continue
        echo "--- $(basename "$f")"
        # One line per model: name, epochs, wall time, frames/s, best validation error.
        sed -n '/^  "models"/,$p' "$f" |
            grep -E '^      "(model|epochs|wall_time_s|frames_per_s|best_val_error_mm|interrupted)"' |
            tr -d ' \n' | sed 's/,"model"/\n"model"/g; s/,$//'
        echo
    done
    nvidia-smi --query-gpu=name,driver_version,memory.used,memory.total --format=csv 2>&1
} 2>&1 | tee -a "$LOG"
log "done in $(elapsed) s"
