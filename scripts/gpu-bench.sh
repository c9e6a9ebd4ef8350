#!/usr/bin/env bash
# The cache's figures on a lent GPU, in one call of the device tool (issue 32, item 5).
#
#   scripts/gpu-bench.sh --prepare       # here: strip and compress the built binaries into .bench/
#   scripts/gpu-bench.sh OUT             # there (or here on lavapipe): write the figures to OUT
#
# --prepare copies, stripped, from "$CARGO_TARGET_DIR/release" (after `cargo build --release
# --locked --workspace --all-targets`): the `nrc` binary and nrc-cache's `gpu_fused`, `backends`
# and `wgpu_training` test binaries (the device self-check: the fused CubeCL kernels, both atomic
# paths, and the custom-ops path's kernels against the CPU path); then it builds `nrc` and
# `gpu_fused` with the cargo feature `vulkan` (the same kernels compiled to SPIR-V on a Vulkan
# adapter: `nrc-spirv`, `gpu_fused-spirv`) and puts the default `nrc` back. The CUDA runtime
# is not built: cubecl-cuda 0.11's build downloads an LLVM bundle, which neither this machine
# nor the device can reach. `.bench/` and the Vulkan loaders `.gl/` are ignored by git and
# travel with `carry` (the device README's recipe for `.gl`).
#
# OUT receives, each step under its own time limit (the whole run under 5 minutes on a GPU):
#   adapter.txt     the adapters, their features and limits (f16, subgroups, float atomics,
#                   cooperative matrices, workgroup memory), nvidia-smi where it exists
#   selfcheck.txt   the wgpu kernels against the CPU path (the three test binaries)
#   selfcheck-spirv.txt  the fused kernels' tests, compiled to SPIR-V
#   bench-wgpu.txt  `nrc bench cache --device wgpu`: training samples/s and inference queries/s
#                   of the hash-grid preset at each batch along the fused path (the default), its
#                   dispatches per step, and fused (f32 MLP, then the f16 MLP where the adapter
#                   has shader-f16) against custom-ops (and generic tensor ops at 2^14) at each
#                   batch
#   bench-spirv.txt the fused path compiled to SPIR-V, at the same batches (its custom-ops
#                   path cannot load WGSL source and says so)
#   bench-cpu.txt   the same on the machine's CPU cores (the fused CPU path), for the ratio
#   profile.txt     per-kernel GPU time, totalled, of 3 s of fused training steps and 3 s of
#                   inference at 2^16 (CubeCL's profile log)
#   train-*.csv     short online `nrc train` runs on the Cornell box, wgpu and CPU, 4 096 and 65 536
#                   records per frame (training batches of at most 2^14), per frame
#   summary.txt     every step's exit status and duration
# GPU_BENCH_BATCHES and GPU_BENCH_FRAMES override the batch list and the online run's frames (a
# software rasteriser needs smaller ones). Worst case, every step at its limit: 595 s.
set -uo pipefail
cd "$(dirname "$0")/.."

if [[ "${1:-}" == "--prepare" ]]; then
  set -e
  rm -rf .bench && mkdir -p .bench
  # Cargo names every executable it built (or found fresh) in its JSON messages: `executable
  # NAME KIND` prints the program (KIND bin) or the integration test (KIND test) called NAME,
  # so neither a binary of another feature set lying in deps/ nor the program's own unit-test
  # harness (also called `nrc`) is taken.
  executable() { python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if (m.get("reason") == "compiler-artifact" and m.get("executable")
            and m["target"]["name"] == sys.argv[1] and sys.argv[2] in m["target"]["kind"]
            and m["profile"]["test"] == (sys.argv[2] == "test")):
        print(m["executable"])' "$1" "$2" | tail -1; }
  # take NAME BINARY: strips BINARY into .bench/NAME (stripped they are 54-62 MB each; xz
  # brings six under the device's 64 MiB carry).
  take() {
    [[ -n "$2" && -x "$2" ]] || { echo "error: $1 was not built (cargo named no executable)"; exit 1; }
    strip -o ".bench/$1" "$2"
  }
  default=$(cargo build --release --locked --workspace --all-targets --message-format=json)
  take nrc "$(executable nrc bin <<<"$default")"
  for name in gpu_fused backends wgpu_training; do
    take "$name" "$(executable "$name" test <<<"$default")"
  done
  # The SPIR-V build of the same binaries that run the fused kernels.
  take nrc-spirv "$(cargo build --release --locked --features vulkan --bin nrc \
    --message-format=json | executable nrc bin)"
  take gpu_fused-spirv "$(cargo test --release --locked -p nrc-cache --features vulkan \
    --test gpu_fused --no-run --message-format=json | executable gpu_fused test)"
  xz -9 -T2 -f .bench/*
  # The feature build replaced target/release/nrc: the default build's command puts it back.
  cargo build --release --locked --workspace --all-targets --quiet
  du -ch .bench/*
  # What travels: the tracked tree, .bench and .gl (if unpacked already), within 64 MiB.
  total=$(du -cb .bench/* | tail -1 | cut -f1)
  tree=$(git ls-files -z | du -cb --files0-from=- | tail -1 | cut -f1)
  gl=$(du -sb .gl 2>/dev/null | cut -f1)
  carry=$((total + tree + ${gl:-0}))
  if (( carry > 64 * 1024 * 1024 )); then
    echo "error: .bench ($((total >> 20)) MiB), the tree ($((tree >> 20)) MiB) and .gl ($((${gl:-0} >> 20)) MiB) exceed the device's 64 MiB carry"
    exit 1
  fi
  exit 0
fi

OUT=${1:?usage: scripts/gpu-bench.sh OUT | --prepare}
mkdir -p "$OUT"
BIN=${GPU_BENCH_BIN:-.bench}
if ls "$BIN"/*.xz >/dev/null 2>&1; then
  unpacked=$(mktemp -d)
  for f in "$BIN"/*.xz; do xz -dc "$f" >"$unpacked/$(basename "$f" .xz)"; done
  chmod +x "$unpacked"/*
  BIN=$unpacked
fi
BATCHES=${GPU_BENCH_BATCHES:-16384 65536 262144 1048576}
FRAMES=${GPU_BENCH_FRAMES:-60}
batch_args=()
for b in $BATCHES; do batch_args+=(--batch "$b"); done
: >"$OUT/summary.txt"

# step NAME LIMIT_S OUTFILE COMMAND...: runs one step under `timeout`, output to OUTFILE.
step() {
  local name=$1 limit=$2 file=$3
  shift 3
  local t0=$SECONDS
  timeout "$limit" "$@" >"$OUT/$file" 2>&1
  local rc=$?
  echo "$name: exit $rc, $((SECONDS - t0)) s ($file)" | tee -a "$OUT/summary.txt"
}

{
  date -u
  uname -a
  nproc
  command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
  ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/nvidia/share/vulkan/icd.d 2>/dev/null
} >"$OUT/adapter.txt" 2>&1
# The adapter lines come from the benchmark's header (nrc_cache::gpu::describe_adapters).
step adapters 40 adapter-lines.txt "$BIN/nrc" bench cache --device wgpu --config hashgrid \
  --batch 1024 --min-ms 1 --no-compare
grep '^wgpu' "$OUT/adapter-lines.txt" >>"$OUT/adapter.txt"

NRC_SKIP_LOG="$OUT/skipped.txt" step selfcheck 90 selfcheck.txt bash -c "s=0; for t in gpu_fused backends wgpu_training; do '$BIN/'\$t --test-threads 1 --nocapture || s=1; done; exit \$s"
if [[ -x "$BIN/gpu_fused-spirv" ]]; then
  NRC_SKIP_LOG="$OUT/skipped.txt" step selfcheck-spirv 40 selfcheck-spirv.txt \
    "$BIN/gpu_fused-spirv" --test-threads 1 --nocapture
fi
step bench-wgpu 120 bench-wgpu.txt "$BIN/nrc" bench cache --device wgpu --config hashgrid \
  "${batch_args[@]}" --min-ms 1000
if [[ -x "$BIN/nrc-spirv" ]]; then
  step bench-spirv 60 bench-spirv.txt "$BIN/nrc-spirv" bench cache --device wgpu --config hashgrid \
    "${batch_args[@]}" --min-ms 1000
fi
step bench-cpu 45 bench-cpu.txt "$BIN/nrc" bench cache --device cpu --config hashgrid \
  --batch 16384 --batch 65536 --min-ms 1000 --no-compare
# CubeCL logs each kernel's time and a summary at every device synchronisation.
CUBECL_DEBUG_LOG="$OUT/profile.log" CUBECL_DEBUG_OPTION=profile \
  step profile 60 profile-run.txt "$BIN/nrc" bench cache --device wgpu --config hashgrid \
  --batch 65536 --min-ms 3000 --no-compare
# Each logged kernel line is `| DURATION | NAME`: total them per kernel, largest first.
if [[ -f "$OUT/profile.log" ]]; then
  python3 - "$OUT/profile.log" >"$OUT/profile.txt" <<'PY'
import re, sys, collections
unit = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
total, count = collections.Counter(), collections.Counter()
for line in open(sys.argv[1], encoding="utf-8", errors="replace"):
    m = re.match(r"\|\s*([0-9.]+)(ns|µs|us|ms|s)\s*\|\s*(.+?)\s*$", line)
    if m:
        name = re.sub(r"\s+", " ", m.group(3))[:160]
        total[name] += float(m.group(1)) * unit[m.group(2)]
        count[name] += 1
whole = sum(total.values()) or 1.0
print(f"{'ms':>10} {'share':>6} {'launches':>8}  kernel (all launches of the profiled run)")
for name, t in total.most_common(40):
    print(f"{t * 1e3:10.3f} {100 * t / whole:5.1f}% {count[name]:8d}  {name}")
print(f"{whole * 1e3:10.3f} 100.0% {sum(count.values()):8d}  total, {len(total)} kernels")
PY
  rm -f "$OUT/profile.log"
fi
for records in 4096 65536; do
  for dev in wgpu cpu; do
    step "train-$dev-$records" 35 "train-$dev-$records.txt" "$BIN/nrc" train \
      --scene scenes/cornell-box.gltf --frames "$FRAMES" --resolution 128 --width 256 --height 256 \
      --records "$records" --batch "$(( records < 16384 ? records : 16384 ))" --device "$dev" \
      --stats "$OUT/train-$dev-$records.csv"
  done
done
echo "total: $SECONDS s" | tee -a "$OUT/summary.txt"
