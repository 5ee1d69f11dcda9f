#!/usr/bin/env bash
# Installs everything (deploy/setup.sh) and runs the main job on a built-in default: a deforming
# cloth falling on a rotating ball, streamed frame by frame through the engine, with per-frame
# separation, self-distance and collision results. Extra arguments go to `proxima demo`.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/deploy/setup.sh"
exec "$here/build/release/clients/proxima" demo "$@"
