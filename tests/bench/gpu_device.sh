#!/usr/bin/env bash
# The GPU checks and benchmarks for a machine with an NVIDIA GPU that has none of our build tools
# or Debian's libraries (the device machine some sessions are lent: Ubuntu 24.04, the NVIDIA
# driver, no compiler for our code, no network). Two steps:
#
#   tests/bench/gpu_device.sh pack [BUILD_DIR] [PACK]   # here: release binaries + the Debian shared
#                                                       # libraries they load + the real frames,
#                                                       # one .tar.xz (default .devrun/pack.tar.xz)
#   tests/bench/gpu_device.sh run  [PACK] [OUT_DIR]     # there: unpack, run the GPU tests and the
#                                                       # DVD benchmarks, logs and JSON into OUT_DIR
#
# The binaries were configured in /work/main with the data in /work/shared/data (compiled-in
# paths: PROXIMA_BINARY_DIR, PROXIMA_DATA_DIR); `run` puts the unpacked tree at those paths
# (symbolic links) when the machine has none. What `run` runs (docs/benchmarks.md, "On an NVIDIA
# H100"): the GPU tests (DvdGpu.*, the snapshot renderer, GpuBackend.* through the daemon,
# GpuLoss.*), the kernel benchmark on the skirt grid, and the end-to-end DVD benchmark (bvh,
# voronoi-cpu, voronoi-gpu) on the five real frame pairs and the seed scenes.
set -uo pipefail

mode="${1:-}"
here="$(cd "$(dirname "$0")/../.." && pwd)"

bins=(
  tests/proxima_unit_tests
  tests/proxima_snapshot_tests
  tests/integration/proxima_integration_tests
  tests/hardening/proxima_hardening_gpu_loss
  server/proximad
  clients/proxima
  tests/bench/proxima_dvd_bench
  tests/bench/proxima_dvd_gpu_bench
)

case "$mode" in
pack)
  build="${2:-build/release}"
  pack="${3:-.devrun/pack.tar.xz}"
  cd "$here" || exit 1
  stage="$(mktemp -d)"
  trap 'rm -rf "$stage"' EXIT
  mkdir -p "$stage/build/release" "$stage/lib" "$stage/data"
  for b in "${bins[@]}"; do
    mkdir -p "$stage/build/release/$(dirname "$b")"
    cp "$build/$b" "$stage/build/release/$b" || exit 1
  done
  # Every shared library the binaries load, except glibc's and the C++ runtime (the machine's
  # own are newer and compatible).
  for b in "${bins[@]}"; do ldd "$build/$b"; done | awk '$2 == "=>" && $3 ~ /^\// {print $3}' |
    sort -u | grep -v -E '/(libc|libm|libpthread|libdl|librt|libstdc\+\+|libgcc_s)\.so|ld-linux' |
    while read -r lib; do cp -L "$lib" "$stage/lib/"; done
  data="$(sed -n 's/^PROXIMA_DATA_DIR:PATH=//p' "$build/CMakeCache.txt")"
  cp -r "$data/frames" "$stage/data/"
  echo "$build" >"$stage/build_dir"
  git rev-parse HEAD >"$stage/commit"
  mkdir -p "$(dirname "$pack")"
  tar -C "$stage" -cf - . | xz -6 -T2 >"$pack"
  ls -la "$pack"
  ;;
run)
  pack="${2:-.devrun/pack.tar.xz}"
  out="${3:-${OUT:-/tmp/gpu-out}}"
  mkdir -p "$out"
  root=/tmp/proxima-gpu
  rm -rf "$root" && mkdir -p "$root" && xz -dc "$pack" | tar -C "$root" -xf - || exit 1
  # The compiled-in paths.
  mkdir -p /work/main/build /work/shared
  [ -e /work/main/build/release ] || ln -s "$root/build/release" /work/main/build/release
  [ -e /work/shared/data ] || ln -s "$root/data" /work/shared/data
  export LD_LIBRARY_PATH="$root/lib"
  if [ ! -e /usr/share/glvnd/egl_vendor.d/10_nvidia.json ] &&
    [ -e /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json ]; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  fi
  B=/work/main/build/release
  step() { # step NAME TIMEOUT COMMAND...: runs it, its output into $out/NAME.log and the console
    local name="$1" limit="$2"
    shift 2
    echo "==== $name ($(date -u +%H:%M:%S))"
    local t0=$SECONDS
    timeout "$limit" "$@" >"$out/$name.log" 2>&1
    local rc=$?
    tail -n "${TAIL:-25}" "$out/$name.log"
    echo "==== $name: exit $rc, $((SECONDS - t0)) s"
  }
  {
    echo "commit $(cat "$root/commit")"
    nvidia-smi -L
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
    lscpu | grep -E 'Model name|^CPU\(s\)'
    uptime
  } 2>&1 | tee "$out/machine.txt"
  TAIL=6 step tests_dvd_gpu 120 "$B/tests/proxima_unit_tests" --gtest_filter='DvdGpu.*:*Egl*:*Gpu*'
  TAIL=6 step tests_snapshot 120 "$B/tests/proxima_snapshot_tests"
  TAIL=6 step tests_gpu_backend 180 "$B/tests/integration/proxima_integration_tests" \
    --gtest_filter='GpuBackend.*'
  TAIL=6 step tests_gpu_loss 180 "$B/tests/hardening/proxima_hardening_gpu_loss"
  TAIL=14 step kernel_bench 120 "$B/tests/bench/proxima_dvd_gpu_bench"
  TAIL=30 step dvd_real 240 "$B/tests/bench/proxima_dvd_bench" --frames 3 --cells auto \
    --scenes real:cloth-funnel,real:armadillo-rollers,real:cloth-ball,real:n-body-simulation,real:rod-twist \
    --json "$out/dvd_real.json"
  TAIL=20 step dvd_seed 90 "$B/tests/bench/proxima_dvd_bench" --frames 3 --cells auto \
    --scenes bowl,breaking,skirt --json "$out/dvd_seed.json"
  ;;
*)
  sed -n '2,17p' "$0"
  exit 2
  ;;
esac
