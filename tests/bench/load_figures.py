#!/usr/bin/env python3
"""Issue #16 item 2's figures, from the load harness (`proxima load`) against a proximad this
script starts (and `proxima_stream_bench` for the stream overhead against a bare gRPC echo):

  1. review: 64 review clients on one 15M-triangle plant served with a cache of M = 160 MB, for
     10 minutes (open loop, --review-rate poses per second each; every other reviewer moves an
     object every 10th step): errors, per-pose latency percentiles, the daemon's RSS over the run
     (the harness's Prometheus samples) and its peak (VmHWM) against M + 256 MB;
  2. streams: 1, 8 and 32 simulator streams of the bowl seed scene and of the real cloth-ball
     frame pair (closed loop, separation per frame): throughput, latency percentiles, the
     daemon's and the harness's own CPU;
  3. overhead: `proxima_stream_bench` (15K and 150K vertices, float32 and float64, the echo in
     the same run).

Each run's JSON report is kept in OUT; a Markdown summary goes to standard output.

  python3 tests/bench/load_figures.py [--build build/release] [--out DIR] [--data ../shared/data]
      [--models DIR] [--review-duration 10m] [--stream-duration 30s] [--only review,streams,echo]
"""
import argparse
import json
import os
import re
import subprocess
import sys
import threading
import time

M_BYTES = 160 * 2**20


def start_daemon(proximad, models, log_path):
    log = open(log_path, "w")
    args = [proximad, "--listen", "127.0.0.1:0", "--metrics-listen", "127.0.0.1:0",
            "--log-level", "warn", "--cache-bytes", str(M_BYTES)]
    if models:
        args += ["--models", models]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=log, text=True)
    lines = [p.stdout.readline(), p.stdout.readline()]
    m = re.match(r"listening on (\S+:\d+)$", lines[0].strip())
    n = re.match(r"metrics on (\S+:\d+)$", lines[1].strip())
    if not (m and n):
        p.kill()
        sys.exit(f"proximad did not print its addresses: {lines!r} (log: {log_path})")
    threading.Thread(target=p.stdout.read, daemon=True).start()
    return p, m.group(1), n.group(1)


def stop_daemon(p):
    peak = None
    try:
        with open(f"/proc/{p.pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    peak = int(line.split()[1]) * 1024
    except OSError:
        pass
    p.terminate()
    try:
        p.wait(60)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()
    return peak


def load(proxima, out, name, args):
    path = os.path.join(out, f"{name}.json")
    cmd = [proxima, "load", *args, "--quiet", "--out", path]
    print(f"# {' '.join(cmd)}", file=sys.stderr, flush=True)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{name}: exit {r.returncode}: {r.stderr}")
    with open(path) as f:
        return json.load(f)


def ms(ns):
    return "-" if ns is None else f"{ns / 1e6:.2f}"


def mib(b):
    return "-" if b is None else f"{b / 2**20:.0f}"


def review(a, proxima, proximad):
    store = os.path.join(a.models, "plant15m")
    if subprocess.run([proxima, "store-info", "--store", store], capture_output=True).returncode:
        os.makedirs(a.models, exist_ok=True)
        subprocess.run([proxima, "import", "--quiet", "--store", store, "--cache-bytes",
                        str(M_BYTES), "--plant", "15M", "--out", os.devnull], check=True)
    p, address, metrics = start_daemon(proximad, a.models, os.path.join(a.out, "review.log"))
    try:
        doc = load(proxima, a.out, "review64", [
            "--server", address, "--metrics", metrics, "--model", "plant15m",
            "--duration", a.review_duration, "--warmup", "10s", "--clients", "review=64",
            "--rate", str(a.review_rate), "--tolerance", "0.05", "--edit-every", "10",
            "--plot", os.path.join(a.out, "review64.png")])
    finally:
        peak = stop_daemon(p)
    pose = doc["kinds"].get("review_pose", {})
    samples = doc["metrics"]["endpoints"][0]["samples"]
    rss = [s["rss_bytes"] for s in samples if s.get("rss_bytes") is not None]
    errors = doc["count"] - doc["statusCodeDistribution"].get("OK", 0)
    print(f"### 64 review clients, 15M-triangle plant, M = 160 MB, {a.review_duration} "
          f"({a.review_rate} poses/s each, open loop)\n")
    print("| calls | errors | poses | pose p50 ms | p90 | p99 | p99.9 | max | "
          "daemon's own time p50 / p99 / max ms | "
          "daemon RSS min-max MiB (samples) | daemon peak RSS MiB (VmHWM) | M + 256 MiB | "
          "daemon cores | harness cores |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---:|---:|---:|")
    pc = pose.get("percentiles", {})
    sp = pose.get("serverPercentiles", {})
    ep = doc["metrics"]["endpoints"][0]["summary"]
    print(f"| {doc['count']} | {errors} | {pose.get('count', 0)} | {ms(pc.get('p50'))} | "
          f"{ms(pc.get('p90'))} | {ms(pc.get('p99'))} | {ms(pc.get('p99.9'))} | "
          f"{ms(pc.get('max'))} | {ms(sp.get('p50'))} / {ms(sp.get('p99'))} / {ms(sp.get('max'))} | "
          f"{mib(min(rss) if rss else None)}-{mib(max(rss) if rss else None)}"
          f" ({len(rss)}) | {mib(peak)} | {mib(M_BYTES + 256 * 2**20)} | "
          f"{ep.get('cpu_cores') or 0:.2f} | {doc['harness']['cpu_cores'] or 0:.2f} |\n")


def streams(a, proxima, proximad):
    p, address, metrics = start_daemon(proximad, None, os.path.join(a.out, "streams.log"))
    rows = []
    try:
        for kind, extra in (("bowl", ["--scene", "bowl"]),
                            ("cloth-ball frames",
                             ["--frames", os.path.join(a.data, "frames", "cloth-ball")])):
            for n in (1, 8, 32):
                clients = f"sim={n}" if kind == "bowl" else f"frames={n}"
                name = f"streams-{kind.split()[0]}-{n}"
                doc = load(proxima, a.out, name, [
                    "--server", address, "--metrics", metrics, "--duration",
                    a.stream_duration, "--warmup", "3s", "--clients", clients, "--queries",
                    "separation", *extra])
                k = doc["kinds"]["sim_frame" if kind == "bowl" else "pair_frame"]
                rows.append((kind, n, doc, k))
    finally:
        stop_daemon(p)
    print(f"### Simulator streams, separation per frame, closed loop, {a.stream_duration} "
          "each (3 s warm-up)\n")
    print("| scene | streams | frames/s | p50 ms | p90 | p99 | p99.9 | errors | daemon cores | "
          "harness cores |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind, n, doc, k in rows:
        pc = k["percentiles"]
        errors = doc["count"] - doc["statusCodeDistribution"].get("OK", 0)
        ep = doc["metrics"]["endpoints"][0]["summary"]
        print(f"| {kind} | {n} | {k['rps']:.1f} | {ms(pc['p50'])} | {ms(pc['p90'])} | "
              f"{ms(pc['p99'])} | {ms(pc['p99.9'])} | {errors} | {ep.get('cpu_cores') or 0:.2f} | "
              f"{doc['harness']['cpu_cores'] or 0:.2f} |")
    print()


def echo(a):
    bench = os.path.join(a.build, "tests", "bench", "proxima_stream_bench")
    r = subprocess.run([bench], capture_output=True, text=True, check=True)
    with open(os.path.join(a.out, "stream_bench.txt"), "w") as f:
        f.write(r.stdout)
    print("### Stream overhead against a bare gRPC echo (proxima_stream_bench)\n")
    print(r.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", default="build/release")
    ap.add_argument("--out", default="/tmp/proxima-load-figures")
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--models", default="/tmp/proxima-models-160m")
    ap.add_argument("--review-duration", default="10m")
    ap.add_argument("--review-rate", type=float, default=10.0)
    ap.add_argument("--stream-duration", default="30s")
    ap.add_argument("--only", default="review,streams,echo")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    proxima = os.path.join(a.build, "clients", "proxima")
    proximad = os.path.join(a.build, "server", "proximad")
    with open("/proc/loadavg") as f:
        load_before = f.read().split()[0]
    nproc = os.cpu_count()
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"Run of {started}, {nproc} cores, 1-minute load {load_before} at the start; "
          f"reports in {a.out}\n")
    parts = a.only.split(",")
    if "review" in parts:
        review(a, proxima, proximad)
    if "streams" in parts:
        streams(a, proxima, proximad)
    if "echo" in parts:
        echo(a)
    with open("/proc/loadavg") as f:
        print(f"1-minute load {f.read().split()[0]} at the end")


if __name__ == "__main__":
    main()
