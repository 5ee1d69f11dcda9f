#!/usr/bin/env bash
# Set-up from nothing on Debian 12, as root: installs every Debian package the project needs,
# then configures and builds with the `release` preset (or the preset named by PROXIMA_PRESET).
# Idempotent (apt skips what is installed, CMake rebuilds only what changed), quiet, and loud on
# failure: any failing step stops the script with its output and a non-zero exit.
#
#   bash deploy/setup.sh            # install + build
#   bash deploy/setup.sh --deps     # install packages only
#
# Node.js and npm (for tests/grpcjs, the daemon driven from Node's grpc-js) come from Debian's
# `nodejs` and `npm` unless `node` / `npm` are already on PATH (a NodeSource `nodejs` brings its
# own npm, and Debian's `npm` would conflict with it); then `npm ci` installs the pinned packages
# of tests/grpcjs/package-lock.json into tests/grpcjs/node_modules (and likewise tests/k8s and
# clients/web, whose page `vite build` then builds into clients/web/dist).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
preset="${PROXIMA_PRESET:-release}"

packages=(
  build-essential cmake ninja-build pkg-config git ca-certificates
  libeigen3-dev libtbb-dev libspdlog-dev libfmt-dev libcli11-dev nlohmann-json3-dev libassimp-dev libgmp-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev libmetis-dev zlib1g-dev
  libegl-dev libegl-mesa0 libgl1-mesa-dri libgles-dev libopengl-dev libgbm-dev libpng-dev
  libfcl-dev libbullet-dev
  python3 python3-grpcio python3-protobuf python3-numpy binutils
  # The Python package's tests: pytest, and a venv that pip installs the package into.
  python3-pytest python3-venv python3-pip python3-setuptools python3-wheel
  # Service hardening: TLS test certificates, Prometheus metrics, libFuzzer targets (clang).
  openssl libssl-dev prometheus-cpp-dev clang libclang-rt-14-dev
  # The lint stage of deploy/test.sh.
  clang-format clang-tidy
  # The CLI's JSON output against docs/json-output.schema.json (tests/cli/test_json_schema.py).
  python3-jsonschema
  # proxima load --plot FILE.png and docs/plots/plot_all.py: plots (gnuplot's pngcairo terminal).
  gnuplot-nox
  # Scale-out (docs/deploy.md): several daemons behind HAProxy (tests/scaleout/test_haproxy.py).
  haproxy
  # The review page's browser test (tests/web): Debian's chromium, driven by playwright-core;
  # the page's sans-serif text renders in Liberation Sans as in the reference screenshots (newer
  # chromium packages no longer pull a font in, and DejaVu's wider glyphs fail the comparison).
  chromium fonts-liberation
)

log() { printf '[setup] %s\n' "$*" >&2; }

run_quiet() {
  # Runs a command, keeping its output unless it fails.
  local out
  out="$(mktemp)"
  if ! "$@" >"$out" 2>&1; then
    cat "$out" >&2
    rm -f "$out"
    log "FAILED: $*"
    exit 1
  fi
  rm -f "$out"
}

install_packages() {
  local missing=()
  command -v node >/dev/null 2>&1 || packages+=(nodejs)
  command -v npm >/dev/null 2>&1 || packages+=(npm)
  for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed'; then
      missing+=("$p")
    fi
  done
  if [ ${#missing[@]} -eq 0 ]; then
    log "all ${#packages[@]} Debian packages present"
    return
  fi
  if [ "$(id -u)" -ne 0 ]; then
    log "missing packages (${missing[*]}) and not root: run this script as root"
    exit 1
  fi
  log "installing ${#missing[@]} Debian packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  run_quiet apt-get update -q
  run_quiet apt-get install -y -q --no-install-recommends "${missing[@]}"
}

npm_packages() {
  # `npm ci` from each lockfile (tests/grpcjs: the daemon from grpc-js; tests/k8s: the Kubernetes
  # manifests' schema check; clients/web: the review page, its gateway and its browser test),
  # skipped while node_modules holds that lockfile's install. playwright-core never downloads a
  # browser: tests/web uses Debian's chromium.
  local name dir stamp want
  export PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1
  for name in tests/grpcjs tests/k8s clients/web; do
    dir="$here/$name"
    stamp="$dir/node_modules/.proxima-package-lock.sha256"
    want="$(sha256sum "$dir/package-lock.json" | cut -d' ' -f1)"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
      log "$name: node_modules matches package-lock.json"
      continue
    fi
    log "$name: npm ci (node $(node --version), npm $(npm --version))"
    cd "$dir"
    run_quiet npm ci --no-audit --no-fund
    cd "$here"
    printf '%s\n' "$want" >"$stamp"
  done
  # The review page, built by vite into clients/web/dist (what clients/web/gateway.js serves).
  log "clients/web: vite build"
  cd "$here/clients/web"
  run_quiet npx --no-install vite build
  cd "$here"
}

build() {
  cd "$here"
  log "configuring (preset $preset)"
  run_quiet cmake --preset "$preset"
  log "building (preset $preset)"
  # Two jobs per core would swap on big TUs; one per core keeps peak memory predictable.
  if ! cmake --build --preset "$preset" -j "$(nproc)" >/tmp/proxima-build.log 2>&1; then
    tail -n 80 /tmp/proxima-build.log >&2
    log "FAILED: build (full log in /tmp/proxima-build.log)"
    exit 1
  fi
  log "built into build/$preset"
}

install_packages
npm_packages
if [ "${1:-}" != "--deps" ]; then
  build
fi
