#!/usr/bin/env bash
# Installs everything (deploy/setup.sh) and runs the whole test suite: unit, property, CLI and the
# benchmark smoke run. This is the README's test command and what CI runs (.ci/run).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/deploy/setup.sh"
cd "$here"
# Keep Mesa's shader cache (later: the EGL backend) out of $HOME on shared machines.
export MESA_SHADER_CACHE_DIR="${MESA_SHADER_CACHE_DIR:-$here/build/mesa-cache}"
ctest --preset release -j "$(nproc)"
