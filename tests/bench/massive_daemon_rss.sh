#!/usr/bin/env bash
# Daemon RSS against the cache budget M on a generated plant (seed 001 §6.3's 160 MB cache):
# for each M, a fresh proximad serves the store, `proxima verify --server` runs a static
# verification, then `proxima review --server` walks a 4,140-triangle avatar along a 600-pose path
# through the plant (poses sent back to back, nearest object on; the p99 is the client's round trip
# over gRPC); the daemon's peak RSS (VmHWM) is read from /proc after both.
#
#   bash tests/bench/massive_daemon_rss.sh [BUILD_DIR] [TRIANGLES] [M_MB ...]
#   bash tests/bench/massive_daemon_rss.sh build/release 15M 30 80 160 400 800
#
# The store is imported once into $PROXIMA_MODELS (default /tmp/proxima-models/plant-TRIANGLES,
# pieces at most 3 MB so that M = 30 MB still holds any two neighbours).
set -euo pipefail
build="${1:-build/release}"
triangles="${2:-15M}"
shift 2 || true
budgets=("$@")
[ ${#budgets[@]} -gt 0 ] || budgets=(30 80 160 400 800)
proxima="$build/clients/proxima"
proximad="$build/server/proximad"
models="${PROXIMA_MODELS:-/tmp/proxima-models}"
name="plant-$triangles"
work="$(mktemp -d)"
trap 'rm -rf "$work"; [ -n "${pid:-}" ] && kill "$pid" 2>/dev/null || true' EXIT

if ! "$proxima" store-info --store "$models/$name" >/dev/null 2>&1; then
  mkdir -p "$models"
  "$proxima" import --quiet --store "$models/$name" --plant "$triangles" --max-piece-bytes 3M >/dev/null
fi

# The avatar (a UV sphere, 46 segments: 4,140 triangles, radius 0.5) and a path through the plant's
# middle at pipe-rack height, 5 cm per pose.
"$proxima" store-info --store "$models/$name" --objects >"$work/info.json"
python3 - "$work" <<'EOF'
import json, math, sys
work = sys.argv[1]
boxes = [o["box"] for o in json.load(open(f"{work}/info.json"))["objects"]]
lo = [min(b["lo"][k] for b in boxes) for k in range(3)]
hi = [max(b["hi"][k] for b in boxes) for k in range(3)]
n, r = 46, 0.5
v = [(0, 0, r)]
for i in range(1, n):
    th = math.pi * i / n
    for j in range(2 * n):
        ph = math.pi * j / n
        v.append((r * math.sin(th) * math.cos(ph), r * math.sin(th) * math.sin(ph), r * math.cos(th)))
v.append((0, 0, -r))
ring = lambda i, j: 1 + (i - 1) * 2 * n + (j % (2 * n))
f = []
for j in range(2 * n):
    f.append((0, ring(1, j), ring(1, j + 1)))
    for i in range(1, n - 1):
        f.append((ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)))
        f.append((ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)))
    f.append((ring(n - 1, j), len(v) - 1, ring(n - 1, j + 1)))
with open(f"{work}/avatar.off", "w") as out:
    out.write(f"OFF\n{len(v)} {len(f)} 0\n")
    out.writelines(f"{x!r} {y!r} {z!r}\n" for x, y, z in v)
    out.writelines(f"3 {a} {b} {c}\n" for a, b, c in f)
e = [hi[k] - lo[k] for k in range(3)]
with open(f"{work}/path.txt", "w") as out:
    for k in range(600):
        x = lo[0] + 0.05 * e[0] + 0.05 * k
        y = lo[1] + 0.5 * e[1] + 0.15 * e[1] * math.sin(0.01 * k)
        z = lo[2] + 0.35 * e[2]
        out.write(f"{x!r} {y!r} {z!r}\n")
EOF

printf '# proximad peak RSS vs cache budget M: %s-triangle plant, %s\n' "$triangles" "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs) ($(nproc) cores)"
printf '%8s %12s %12s %10s %14s\n' M_MB rss_peak_MB rss-M_MB verify_s review_p99_ms
for m in "${budgets[@]}"; do
  "$proximad" --listen 127.0.0.1:0 --models "$models" --cache-bytes $((m * 1048576)) --gpu off \
    >"$work/daemon.log" 2>&1 &
  pid=$!
  for _ in $(seq 100); do grep -q '^listening on' "$work/daemon.log" && break; sleep 0.1; done
  addr="$(sed -n 's/^listening on \([^ ]*\).*/\1/p' "$work/daemon.log" | head -1)"
  t0=$(date +%s.%N)
  "$proxima" verify --quiet --server "$addr" --model "$name" --tolerance 0 --out "$work/verify.json"
  t1=$(date +%s.%N)
  "$proxima" review --quiet --server "$addr" --model "$name" --avatar "$work/avatar.off" \
    --path "$work/path.txt" --tolerance 0.05 --out "$work/review.json"
  hwm=$(awk '/VmHWM/ {print $2}' "/proc/$pid/status")
  p99=$(python3 -c "import json,sys; d=json.load(open('$work/review.json')); print('%.2f' % d['latency_ms']['p99'])")
  kill "$pid"; wait "$pid" 2>/dev/null || true; pid=
  printf '%8d %12.1f %12.1f %10.2f %14s\n' "$m" "$(echo "$hwm/1024" | bc -l)" \
    "$(echo "$hwm/1024 - $m" | bc -l)" "$(echo "$t1 - $t0" | bc -l)" "$p99"
done
