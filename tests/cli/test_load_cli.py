#!/usr/bin/env python3
"""`proxima load` (issue #16 item 1) against a proximad it starts: a short run of simulator and
review clients (one reviewer editing) and a verify client on a small generated plant, with the daemon's Prometheus
endpoint sampled. Checks the report: calls of every kind, no errors, percentiles in order, the
ghz histogram and status codes summing to the count, metric samples with RSS and CPU, the
per-second timeline, the text summary and the PNG plot (when gnuplot is installed); and usage
errors (an unknown client kind, a metrics host that is neither loopback nor a --server) exit 2
with one line. The CI version of the issue's load run: a few seconds, not 30.
A frames client streams a real frame pair of DATA_DIR/frames when the folder is there.
Usage: test_load_cli.py PROXIMA PROXIMAD [DATA_DIR]."""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import unittest

PROXIMA, PROXIMAD = sys.argv[1], sys.argv[2]
DATA = sys.argv[3] if len(sys.argv) > 3 else ""

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import run_program as run  # noqa: E402

# The kinds measured after the warm-up (the reviewers join during it: review_join is in the
# timeline only).
KINDS = {"sim_scene", "sim_frame", "review_pose", "review_edit", "verify_model"}


class LoadCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-load-cli-")
        plant = os.path.join(cls.tmp, "plant")
        models = os.path.join(cls.tmp, "models")
        p = run(PROXIMA, "generate", "plant", "--triangles", "8K", "--dir", plant, "--quiet")
        assert p.returncode == 0, p.stderr
        p = run(PROXIMA, "import", "--store", os.path.join(models, "plant"), "--quiet",
                os.path.join(plant, "scene.json"))
        assert p.returncode == 0, p.stderr
        cls.log = tempfile.TemporaryFile(mode="w+")
        cls.daemon = subprocess.Popen(
            [PROXIMAD, "--listen", "127.0.0.1:0", "--metrics-listen", "127.0.0.1:0", "--models",
             models], stdout=subprocess.PIPE, stderr=cls.log, text=True)
        lines = []

        def first_two():
            for _ in range(2):
                lines.append(cls.daemon.stdout.readline())

        reader = threading.Thread(target=first_two, daemon=True)
        reader.start()
        reader.join(30)
        m = re.match(r"listening on (\S+:\d+)$", lines[0].strip()) if lines else None
        n = re.match(r"metrics on (\S+:\d+)$", lines[1].strip()) if len(lines) > 1 else None
        if not (m and n):
            cls.stop_daemon()
            raise RuntimeError(f"proximad did not print its addresses: {lines!r}")
        cls.address, cls.metrics = m.group(1), n.group(1)
        threading.Thread(target=cls.daemon.stdout.read, daemon=True).start()
        # The one load run the checks read (about 6 s: 1 s of warm-up, 5 s measured).
        cls.png = os.path.join(cls.tmp, "load.png")
        cls.have_gnuplot = shutil.which("gnuplot") is not None
        plot = ["--plot", cls.png] if cls.have_gnuplot else []
        cls.load_run = run(PROXIMA, "load", "--server", cls.address, "--duration", "6s",
                           "--warmup", "1s", "--clients", "sim=2,review=2,verify=1", "--scene",
                           "bowl,breaking", "--episode-frames", "8", "--queries",
                           "separation,collisions,ccd", "--edit-every", "3", "--metrics",
                           f"http://{cls.metrics}/metrics", "--json", *plot, timeout=120)

    @classmethod
    def stop_daemon(cls):
        cls.daemon.send_signal(signal.SIGTERM)
        try:
            cls.daemon.wait(60)
        except subprocess.TimeoutExpired:
            cls.daemon.kill()
            cls.daemon.wait()

    @classmethod
    def tearDownClass(cls):
        cls.stop_daemon()
        cls.daemon.stdout.close()
        cls.log.close()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def report(self):
        self.assertEqual(self.load_run.returncode, 0, self.load_run.stderr)
        out = self.load_run.stdout.splitlines()
        self.assertEqual(len(out), 1, "one line of JSON")
        return json.loads(out[0])

    def check_ghz(self, name, k):
        n = k["count"]
        self.assertGreater(n, 0, name)
        self.assertLessEqual(k["fastest"], k["average"], name)
        self.assertLessEqual(k["average"], k["slowest"], name)
        p = k["percentiles"]
        self.assertLessEqual(k["fastest"], p["p50"], name)
        self.assertTrue(p["p50"] <= p["p90"] <= p["p99"] <= p["p99.9"] <= p["max"], (name, p))
        self.assertEqual(p["max"], k["slowest"], name)
        dist = k["latencyDistribution"]
        self.assertEqual([d["percentage"] for d in dist], [10, 25, 50, 75, 90, 95, 99])
        lat = [d["latency"] for d in dist]
        self.assertEqual(lat, sorted(lat), name)
        self.assertEqual(dist[2]["latency"], p["p50"], name)
        # ghz's histogram: 11 marks (seconds) from the fastest to the slowest.
        h = k["histogram"]
        self.assertEqual(len(h), 11, name)
        self.assertEqual(sum(b["count"] for b in h), n, name)
        self.assertAlmostEqual(sum(b["frequency"] for b in h), 1.0, places=9)
        marks = [b["mark"] for b in h]
        self.assertEqual(marks, sorted(marks), name)
        self.assertAlmostEqual(marks[-1], k["slowest"] * 1e-9, places=12)
        self.assertEqual(sum(k["statusCodeDistribution"].values()), n, name)
        self.assertEqual(k["statusCodeDistribution"], {"OK": n}, (name, k["errorDistribution"]))
        self.assertEqual(k["errorDistribution"], {}, name)
        self.assertGreater(k["rps"], 0, name)

    def test_report(self):
        doc = self.report()
        self.assertEqual(doc["servers"], [self.address])
        self.assertEqual(doc["endReason"], "timeout")
        self.assertRegex(doc["date"], r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ$")
        self.assertEqual(doc["clients"],
                         {"sim": 2, "frames": 0, "review": 2, "verify": 1, "play": 0})
        self.assertEqual(doc["models"], ["plant"])
        self.assertEqual(set(doc["kinds"]), KINDS, doc["kinds"].keys())
        for name, k in doc["kinds"].items():
            self.check_ghz(name, k)
        # Review poses carry the daemon's own time: ordered, and within each pose's latency
        # (which adds the queueing and the transport), so no percentile above the latency's.
        pose = doc["kinds"]["review_pose"]
        sp = pose["serverPercentiles"]
        self.assertTrue(0 < sp["p50"] <= sp["p90"] <= sp["p99"] <= sp["p99.9"] <= sp["max"], sp)
        for q in ("p50", "p90", "p99", "p99.9", "max"):
            self.assertLessEqual(sp[q], pose["percentiles"][q], q)
        self.assertNotIn("serverPercentiles", doc["kinds"]["sim_frame"])
        # The top level is a ghz report over every kind.
        self.check_ghz("all", doc)
        self.assertEqual(doc["count"], sum(k["count"] for k in doc["kinds"].values()))
        self.assertAlmostEqual(doc["measured_seconds"], 5.0, delta=1.0)
        self.assertAlmostEqual(doc["total"], doc["measured_seconds"] * 1e9, delta=2)
        self.assertGreater(doc["warmup_count"], 0)
        # The timeline covers every call, warm-up included.
        self.assertEqual(sum(s["kinds"].get("review_join", 0) for s in doc["timeline"]), 2)
        self.assertEqual(sum(s["count"] for s in doc["timeline"]),
                         doc["count"] + doc["warmup_count"])
        # The harness's own share of the machine over the measured part: five client threads
        # and the sampler, some CPU, less than every core of the machine at once.
        h = doc["harness"]
        self.assertEqual(h["threads"], 6)
        self.assertGreater(h["cpu_seconds"], 0)
        self.assertGreater(h["cpu_cores"], 0)
        self.assertLess(h["cpu_cores"], os.cpu_count() + 0.5)
        self.assertGreater(h["rss_bytes_max"], 1 << 20)

    def test_metrics_samples(self):
        doc = self.report()
        (endpoint,) = doc["metrics"]["endpoints"]
        self.assertEqual(endpoint["url"], f"http://{self.metrics}/metrics")
        samples = endpoint["samples"]
        self.assertGreaterEqual(len(samples), 5, samples)
        ts = [s["t"] for s in samples]
        self.assertEqual(ts, sorted(ts))
        for s in samples:
            self.assertGreater(s["rss_bytes"], 1 << 20)
            self.assertGreaterEqual(s["cpu_seconds"], 0)
            self.assertIsNotNone(s["cache_hits"])
        cpu = [s["cpu_seconds"] for s in samples]
        self.assertEqual(cpu, sorted(cpu), "a counter never goes back")
        self.assertGreater(cpu[-1], cpu[0], "the daemon worked during the run")
        frames = [s["frames"] for s in samples]
        self.assertGreater(frames[-1], frames[0])
        summary = endpoint["summary"]
        self.assertGreater(summary["cpu_seconds"], 0)
        self.assertGreater(summary["rss_bytes_max"], 1 << 20)
        self.assertEqual(doc["metrics"]["failed_scrape_count"], 0)

    def test_progress_and_plot(self):
        self.report()
        progress = [x for x in self.load_run.stderr.splitlines() if x.startswith("load ")]
        self.assertGreaterEqual(len(progress), 5, self.load_run.stderr)
        self.assertIn("(warm-up)", progress[0])
        self.assertIn("0 errors", progress[-1])
        if not self.have_gnuplot:
            self.skipTest("gnuplot is not installed (Debian: gnuplot-nox)")
        with open(self.png, "rb") as f:
            self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
        self.assertGreater(os.path.getsize(self.png), 10000)

    def test_max_calls(self):
        # Bounded in count: 4 clients, 50 calls in all: 12 each, then the run ends by itself.
        p = run(PROXIMA, "load", "--server", self.address, "--duration", "60s", "--warmup", "0",
                "--clients", "sim=4", "--scene", "bowl", "--max-calls", "50", "--json", "--quiet",
                timeout=60)
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        self.assertEqual(doc["count"] + doc["warmup_count"], 48)
        self.assertEqual(doc["endReason"], "normal")
        self.assertLess(doc["measured_seconds"], 30)

    def test_text_summary(self):
        # Two --server addresses (the same daemon twice): the clients are spread over both.
        p = run(PROXIMA, "load", "--server", self.address, "--server", self.address, "--duration",
                "1500ms", "--warmup", "500ms", "--clients", "sim=2", "--scene", "bowl", "--quiet",
                timeout=60)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(p.stderr, "")
        lines = p.stdout.splitlines()
        self.assertLessEqual(len(lines), 25, "one screen")
        self.assertTrue(lines[0].startswith("load: "), lines[0])
        self.assertTrue(lines[0].endswith(f"against {self.address} {self.address}"), lines[0])
        self.assertTrue(any(x.startswith("sim_frame ") for x in lines), p.stdout)
        self.assertTrue(any(x.startswith("all ") for x in lines), p.stdout)

    def test_usage_errors(self):
        cases = [
            (["--clients", "sim=1,robot=2"], "unknown client kind 'robot'"),
            (["--clients", "sim=x"], "whole number"),
            (["--clients", "sim=0"], "no clients"),
            (["--duration", "5 parsecs"], "duration"),
            (["--duration", "2s", "--warmup", "3s"], "shorter than --duration"),
            (["--queries", "separation,telepathy"], "unknown query 'telepathy'"),
            (["--scene", "moon"], "unknown scene 'moon'"),
            (["--metrics", "10.1.2.3:9464"], "loopback"),
            (["--clients", "frames=1"], "frames clients need --frames DIR"),
            (["--clients", "play=1"], "play clients need --sequence DIR"),
        ]
        for extra, message in cases:
            p = run(PROXIMA, "load", "--server", self.address, *extra)
            self.assertEqual(p.returncode, 2, (extra, p.stderr))
            self.assertEqual(p.stdout, "")
            self.assertIn(message, p.stderr, extra)
            self.assertIn("proxima load --help", p.stderr)

    def test_real_frame_pair(self):
        pair = os.path.join(DATA, "frames", "n-body-simulation")
        if not os.path.isdir(pair):
            self.skipTest(f"no real frames at {pair} (../shared/data/frames)")
        p = run(PROXIMA, "load", "--server", self.address, "--duration", "4s", "--warmup", "0",
                "--clients", "frames=1", "--frames", pair, "--queries", "separation",
                "--json", "--quiet", timeout=60)
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        self.assertEqual(doc["frame_pairs"], [pair])
        self.assertEqual(set(doc["kinds"]), {"pair_scene", "pair_frame"})
        self.assertEqual(doc["kinds"]["pair_scene"]["count"], 1)
        self.check_ghz("pair_frame", doc["kinds"]["pair_frame"])

    def test_recorded_sequence(self):
        # play clients: `proxima play`'s player on a generated sequence whose balls break into
        # pieces halfway (a topology change mid-stream), over and over; the player checks every
        # answer against the frame's objects, so an answer that missed the change is an error.
        with tempfile.TemporaryDirectory() as tmp:
            seq = os.path.join(tmp, "breaking")
            p = run(PROXIMA, "generate", "sequence", "--scene", "breaking", "--frames", "8",
                    "--dir", seq, "--quiet", "--out", os.path.join(tmp, "gen.json"))
            self.assertEqual(p.returncode, 0, p.stderr)
            p = run(PROXIMA, "load", "--server", self.address, "--duration", "4s", "--warmup",
                    "0", "--clients", "play=1", "--sequence", seq, "--queries",
                    "separation,collisions", "--json", "--quiet", timeout=60)
            self.assertEqual(p.returncode, 0, p.stderr)
            doc = json.loads(p.stdout)
            self.assertEqual(doc["sequences"], [seq])
            self.assertEqual(doc["clients"]["play"], 1)
            self.assertEqual(set(doc["kinds"]), {"play_scene", "play_frame"})
            self.assertGreaterEqual(doc["kinds"]["play_scene"]["count"], 1)
            self.assertEqual(doc["statusCodeDistribution"], {"OK": doc["count"]})
            # Frame 0 creates the scene; the others, the break at frame 4 among them, are frames.
            self.assertGreaterEqual(doc["kinds"]["play_frame"]["count"], 7)
            self.check_ghz("play_frame", doc["kinds"]["play_frame"])

    def test_failed_preconditions(self):
        # A daemon that does not answer, and a model that is not served: exit 1 before any load.
        p = run(PROXIMA, "load", "--server", "127.0.0.1:1", "--duration", "1s", "--warmup", "0",
                timeout=60)
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("UNAVAILABLE", p.stderr)
        p = run(PROXIMA, "load", "--server", self.address, "--clients", "review=1", "--model",
                "nope", "--duration", "1s", "--warmup", "0")
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("does not serve the model 'nope'", p.stderr)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
