#!/usr/bin/env bash
# Installs everything (deploy/setup.sh), starts the daemon proximad on a free loopback port and
# runs the main job against it: a deforming cloth falling on a rotating ball, streamed frame by
# frame over one gRPC stream, with per-frame separation, self-distance and collision results and
# each frame's round trip. Extra arguments go to `proxima demo` (e.g. --scene breaking --frames 16
# --json). The daemon is then stopped with SIGTERM and must exit with status 0; any failure stops
# the script loudly (the daemon's log is shown) with a non-zero exit, and never leaves it running.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/deploy/setup.sh"

proximad="$here/build/release/server/proximad"
proxima="$here/build/release/clients/proxima"
work="$(mktemp -d)"
daemon_pid=""

log() { printf '[demo] %s\n' "$*" >&2; }

show_daemon_log() {
  log "proximad's standard error:"
  cat "$work/stderr" >&2 || true
}

cleanup() {
  if [ -n "$daemon_pid" ]; then
    kill -KILL "$daemon_pid" 2>/dev/null || true
    wait "$daemon_pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT
# Ctrl-C or a TERM to this script still runs the EXIT trap (and so stops the daemon).
trap 'exit 130' INT
trap 'exit 143' TERM

"$proximad" --listen 127.0.0.1:0 >"$work/stdout" 2>"$work/stderr" &
daemon_pid=$!

# The daemon's first stdout line is `listening on HOST:PORT`, written once it accepts calls.
# Wait for the whole line (newline included), for at most 30 s, and stop early if it dies.
address=""
for _ in $(seq 300); do
  if [ "$(wc -l <"$work/stdout")" -ge 1 ]; then
    line="$(head -n 1 "$work/stdout")"
    if [[ "$line" != "listening on "* ]]; then
      log "FAILED: proximad's first line is not 'listening on HOST:PORT': $line"
      show_daemon_log
      exit 1
    fi
    address="${line#listening on }"
    break
  fi
  if ! kill -0 "$daemon_pid" 2>/dev/null; then
    break
  fi
  sleep 0.1
done
if [ -z "$address" ]; then
  if kill -0 "$daemon_pid" 2>/dev/null; then
    log "FAILED: proximad did not report its address within 30 s"
  else
    status=0
    wait "$daemon_pid" || status=$?
    daemon_pid=""
    log "FAILED: proximad exited with status $status before listening"
  fi
  show_daemon_log
  exit 1
fi
log "proximad listening on $address (pid $daemon_pid)"

demo_status=0
"$proxima" demo --server "$address" "$@" || demo_status=$?

# SIGTERM drains in-flight calls, then exits 0. A watchdog turns a hang into a loud failure.
kill -TERM "$daemon_pid"
( sleep 60; kill -KILL "$daemon_pid" 2>/dev/null ) &
watchdog=$!
daemon_status=0
wait "$daemon_pid" || daemon_status=$?
daemon_pid=""
kill "$watchdog" 2>/dev/null || true
wait "$watchdog" 2>/dev/null || true

if [ "$demo_status" -ne 0 ]; then
  log "FAILED: proxima demo exited with status $demo_status"
  show_daemon_log
  exit "$demo_status"
fi
if [ "$daemon_status" -ne 0 ]; then
  log "FAILED: proximad exited with status $daemon_status after SIGTERM (137: killed after 60 s)"
  show_daemon_log
  exit 1
fi
log "proximad stopped cleanly"
