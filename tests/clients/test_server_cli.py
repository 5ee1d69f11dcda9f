#!/usr/bin/env python3
"""End to end, client against daemon: starts `proximad --listen 127.0.0.1:0`, checks that
`proxima distance --server` prints exactly what `--local` prints (apart from `stats`) on touching,
crossing and separated boxes, split components, self / collision / tolerance / PNS queries and
chunked uploads; that the server demo reports what the local demo reports, through a topology
change; that daemon errors reach the user as `proxima: error: CODE: message`; that the Python
example works (the package itself: tests/python); that docs/api.md's examples are the code and
print what it says; and that
SIGTERM stops the daemon with exit status 0.

Usage: test_server_cli.py --proxima PROXIMA --proximad PROXIMAD --python PYTHON --example EXAMPLE
                          --api-doc docs/api.md --api-doc-example API_DOC_EXAMPLE
(PYTHON: an interpreter with Debian's grpc, google.protobuf and numpy modules, /usr/bin/python3;
PYTHONPATH must hold the `proxima` package: build/<preset>/python.)"""
import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

parser = argparse.ArgumentParser()
parser.add_argument("--proxima", required=True)
parser.add_argument("--proximad", required=True)
parser.add_argument("--python", default="/usr/bin/python3")
parser.add_argument("--example", required=True)
parser.add_argument("--api-doc", required=True,
                    help="docs/api.md, whose snippets are checked against the code")
parser.add_argument("--api-doc-example", required=True,
                    help="the C++ example of docs/api.md, compiled")
ARGS, UNITTEST_ARGS = parser.parse_known_args()

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon as SharedDaemon  # noqa: E402
from cli_helpers import box_mesh, strip_stats, write_off  # noqa: E402
from cli_helpers import run_program as run  # noqa: E402


def grid_off(n, z):
    """An n x n wavy height field at height ~z: (n+1)^2 vertices, 2 n^2 triangles."""
    v = [(i / n, j / n, z + 0.01 * ((i * 7 + j * 3) % 5)) for j in range(n + 1)
         for i in range(n + 1)]
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    return v, f


class Daemon(SharedDaemon):
    def __init__(self, *flags):
        super().__init__(ARGS.proximad, *flags)


class ServerCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-e2e-")
        cls.files = {}
        shapes = {
            "a": [box_mesh((0, 0, 0), (1, 1, 1))],
            "apart": [box_mesh((1.5, 0, 0), (2.5, 1, 1))],
            "touching": [box_mesh((1, 0.25, 0.25), (1.5, 0.75, 0.75))],
            "crossing": [box_mesh((0.5, 0.5, 0.5), (1.5, 1.5, 1.5))],
            "two": [box_mesh((0, 0, 0), (1, 1, 1)), box_mesh((0, 0, 1.25), (1, 1, 2))],
            # 52K vertices, 102K triangles: both buffers take two 1 MiB upload chunks.
            "grid": [grid_off(227, 1.1)],
            # Two frames of one scene: the second box sweeps through the first.
            "sweep0": [box_mesh((0, 0, 0), (1, 1, 1)), box_mesh((2, 0.25, 0.25), (2.5, 0.75, 0.75))],
            "sweep1": [box_mesh((0, 0, 0), (1, 1, 1)),
                       box_mesh((-1, 0.25, 0.25), (-0.5, 0.75, 0.75))],
        }
        for name, parts in shapes.items():
            cls.files[name] = os.path.join(cls.tmp, name + ".off")
            write_off(cls.files[name], parts)
        cls.daemon = Daemon()

    @classmethod
    def tearDownClass(cls):
        status = cls.daemon.stop()
        log = cls.daemon.log()
        cls.daemon.close()
        if status != 0:
            raise AssertionError(f"proximad exited with {status} after SIGTERM; stderr:\n{log}")

    def json_of(self, *args):
        p = run(ARGS.proxima, *args)
        self.assertEqual(p.returncode, 0, f"{args}: {p.stderr}")
        return json.loads(p.stdout)

    def assert_same_as_local(self, *args, server_flags=()):
        files = [self.files[a] if a in self.files else a for a in args]
        local = self.json_of("distance", "--local", "--json", *files)
        default = self.json_of("distance", "--json", *files)
        remote = self.json_of("distance", "--server", self.daemon.address, *server_flags,
                              "--json", *files)
        self.assertIn("stats", remote)
        self.assertEqual(strip_stats(local), strip_stats(default))
        # Exact equality, floats included: float64 on the wire and the same engine.
        self.assertEqual(strip_stats(local), strip_stats(remote), f"{args} {server_flags}")
        return remote

    def test_check_config(self):
        # The effective configuration, every key, flags over the file; it round-trips as a file;
        # docs/server.md documents every key; a bad value is exit 2 with a message.
        conf = os.path.join(self.tmp, "proximad.json")
        with open(conf, "w") as f:
            json.dump({"max-scenes": 3, "log-level": "warn"}, f)
        p = run(ARGS.proximad, "--config", conf, "--max-scenes", "7", "--gpu", "off",
                "--check-config")
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        self.assertEqual(doc["max-scenes"], 7)
        self.assertEqual(doc["log-level"], "warn")
        self.assertEqual(doc["gpu"], "off")
        again = os.path.join(self.tmp, "effective.json")
        with open(again, "w") as f:
            f.write(p.stdout)
        p2 = run(ARGS.proximad, "--config", again, "--check-config")
        self.assertEqual(p2.returncode, 0, p2.stderr)
        self.assertEqual(json.loads(p2.stdout), doc)
        server_md = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "docs",
                                 "server.md")
        with open(server_md) as f:
            documented = f.read()
        for key in doc:
            self.assertIn(f"`--{key}` / `{key}`", documented, f"{key} is not in docs/server.md")
        # The shipped configuration file (deploy/proximad.json) is valid and is the defaults.
        shipped = os.path.join(os.path.dirname(server_md), "..", "deploy", "proximad.json")
        defaults = run(ARGS.proximad, "--check-config")
        from_file = run(ARGS.proximad, "--config", shipped, "--check-config")
        self.assertEqual(defaults.returncode, 0, defaults.stderr)
        self.assertEqual(from_file.returncode, 0, from_file.stderr)
        self.assertEqual(json.loads(from_file.stdout), json.loads(defaults.stdout))
        bad = run(ARGS.proximad, "--gpu", "sometimes", "--check-config")
        self.assertEqual(bad.returncode, 2)
        self.assertIn("gpu", bad.stderr)

    def test_ccd_server_equals_local(self):
        args = ("ccd", "--split-components", "--json", self.files["sweep0"], self.files["sweep1"])
        local = self.json_of(*args)
        remote = self.json_of(*args[:1], "--server", self.daemon.address, *args[1:])
        self.assertEqual(strip_stats(local), strip_stats(remote))
        self.assertGreater(len(local["pairs"]), 0)
        self.assertEqual(len(local["object_pairs"]), 1)
        # The small box (x from 2 to -1 over the frame) first meets x = 1 at t = 1/3.
        self.assertLessEqual(local["earliest"]["toi"], 1 / 3)
        self.assertGreater(local["earliest"]["toi"], 1 / 3 - 1e-5)

    def test_distance_boxes_apart_touching_crossing(self):
        doc = self.assert_same_as_local("a", "apart")
        self.assertEqual(doc["objects"][0]["separation"]["distance"], 0.5)
        doc = self.assert_same_as_local("--collisions", "a", "touching")
        self.assertEqual(doc["objects"][0]["separation"]["distance"], 0.0)
        doc = self.assert_same_as_local("--collisions", "--tolerance", "0.1", "a", "crossing")
        self.assertGreater(len(doc["collisions"]), 0)
        doc = self.assert_same_as_local("--penetration", "a", "crossing")
        self.assertEqual(len(doc["penetrations"]), 1)
        self.assertGreater(doc["penetrations"][0]["depth"], 0.0)
        self.assert_same_as_local("a")  # alone: no other object, nulls

    def test_distance_components_self_collisions_tolerance(self):
        doc = self.assert_same_as_local("--split-components", "--self", "--collisions",
                                        "--tolerance", "0.3", "two")
        self.assertEqual(len(doc["self"]), 24)
        self.assertGreater(len(doc["within"]), 0)
        for culler in ("brute", "bvh"):
            self.assert_same_as_local("--culler", culler, "--split-components", "--self",
                                      "--collisions", "--tolerance", "0.3", "--pns", "two", "a",
                                      "apart", "crossing")

    def test_distance_through_uploads(self):
        # 0: every object uploaded; 400: the first box inline (~370 bytes), the rest uploaded.
        for inline in ("0", "400"):
            self.assert_same_as_local("--split-components", "--self", "--tolerance", "0.3",
                                      "two", "a", "apart",
                                      server_flags=("--inline-mesh-bytes", inline))
        # Separation only: a tolerance or self query on a fine grid is quadratic in its output.
        doc = self.assert_same_as_local("grid", "a")
        self.assertEqual(doc["objects"][0]["triangle_count"], 2 * 227 * 227)
        self.assertAlmostEqual(doc["objects"][0]["separation"]["distance"], 0.1, places=12)

    def test_distance_text_mode(self):
        p = run(ARGS.proxima, "distance", "--server", self.daemon.address,
                self.files["a"], self.files["apart"])
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("distance 0.5 to", p.stdout)

    def test_daemon_errors_reach_the_user(self):
        small = Daemon("--max-triangles-per-scene", "20")
        try:
            p = run(ARGS.proxima, "distance", "--server", small.address, "--json",
                    self.files["a"], self.files["apart"])
            self.assertEqual(p.returncode, 1)
            self.assertEqual(p.stdout, "")
            self.assertRegex(p.stderr, r"^proxima: error: RESOURCE_EXHAUSTED: .*\S")
            self.assertIn("20", p.stderr)
        finally:
            status = small.stop()
            log = small.log()
            small.close()
            self.assertEqual(status, 0, log)
        # Nobody listens on port 1: UNAVAILABLE after the connect timeout.
        p = run(ARGS.proxima, "distance", "--server", "127.0.0.1:1", self.files["a"])
        self.assertEqual(p.returncode, 1)
        self.assertRegex(p.stderr, r"^proxima: error: UNAVAILABLE: cannot reach proximad at "
                                   r"127\.0\.0\.1:1")
        p = run(ARGS.proxima, "distance", "--local", "--server", self.daemon.address,
                self.files["a"])
        self.assertNotEqual(p.returncode, 0)

    def demo_lines(self, *args):
        p = run(ARGS.proxima, "demo", "--json", *args)
        self.assertEqual(p.returncode, 0, p.stderr)
        return [json.loads(line) for line in p.stdout.splitlines()]

    def test_demo_matches_local(self):
        keys = ("frame", "object_count", "triangle_count", "min_separation", "min_self_distance",
                "collision_count")
        # `breaking` replaces objects by fragments mid-sequence: the id translation at work.
        for scene, frames in (("breaking", "6"), ("bowl", "3")):
            local = self.demo_lines("--scene", scene, "--frames", frames)
            remote = self.demo_lines("--scene", scene, "--frames", frames, "--server",
                                     self.daemon.address)
            self.assertEqual(len(local), int(frames))
            self.assertEqual([{k: x[k] for k in keys} for x in local],
                             [{k: x[k] for k in keys} for x in remote], scene)
            for x in remote:
                self.assertGreater(x["round_trip_ms"], 0)
                self.assertGreater(x["stats"]["exact_tests"], 0)
            if scene == "breaking":
                self.assertGreater(len({x["object_count"] for x in local}), 1, "no topology change")
        p = run(ARGS.proxima, "demo", "--scene", "bowl", "--frames", "2", "--server",
                self.daemon.address)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("rtt-ms", p.stdout)
        # 3 header lines, 2 frames, the per-frame spread of engine time and round trip
        lines = p.stdout.strip().splitlines()
        self.assertEqual(len(lines), 7)
        self.assertTrue(lines[5].startswith("engine time per frame, frames 1..1: median"), lines[5])
        self.assertIn("p99/median", lines[6])

    def test_a_daemon_dying_mid_stream_is_named(self):
        # Issue #18: "UNAVAILABLE: Socket closed" named neither the daemon nor the last frame.
        daemon = Daemon("--gpu", "off")
        demo = subprocess.Popen([ARGS.proxima, "demo", "--server", daemon.address, "--scene",
                                 "cloth-ball", "--frames", "100000"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            frames = 0
            for line in demo.stdout:
                if re.match(r"^\s*\d+\s+\d+\s+\d+", line):
                    frames += 1
                    if frames == 3:
                        break
            self.assertEqual(frames, 3, "the demo answered no frames")
            daemon.proc.kill()
            daemon.proc.wait()
            _, err = demo.communicate(timeout=60)
        finally:
            if demo.poll() is None:
                demo.kill()
                demo.wait()
            daemon.proc.stdout.close()
            daemon.close()
        self.assertEqual(demo.returncode, 1, err)
        self.assertIn("UNAVAILABLE", err)
        self.assertIn("stream to the daemon at " + daemon.address + " broke at frame", err)
        self.assertRegex(err, r"last frame answered: \d+\)")

    def test_info(self):
        info = self.json_of("info", "--server", self.daemon.address, "--json")
        self.assertEqual(info["api"], "proxima.v1")
        self.assertTrue(info["version"])
        self.assertGreater(info["limits"]["max_frames_in_flight"], 0)
        p = run(ARGS.proxima, "info", "--server", self.daemon.address)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("proxima.v1", p.stdout)

    def test_python_example(self):
        p = run(ARGS.python, ARGS.example, self.daemon.address)
        self.assertEqual(p.returncode, 0, p.stderr)
        lines = p.stdout.splitlines()
        self.assertEqual(len(lines), 2, p.stdout)
        self.assertTrue(lines[0].startswith("distance a-b: 0.5 "), lines[0])
        self.assertTrue(lines[1].endswith("distance a-b: 0.25"), lines[1])

    def test_api_doc_snippets(self):
        with open(ARGS.api_doc) as f:
            doc = f.read()
        # The C++ example (compiled from the page by CMake) prints what the page says it prints.
        printed = re.search(r"It prints:\n\n```\n(.*?)```", doc, re.S)
        self.assertIsNotNone(printed, "docs/api.md: no 'It prints:' block")
        p = run(ARGS.api_doc_example, self.daemon.address)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(p.stdout, printed.group(1))
        # The page's first Python block is the example in clients/python/examples (run by
        # test_python_example); tests/python/test_docs.py runs the others.
        blocks = re.findall(r"```python\n(.*?)```", doc, re.S)
        self.assertGreater(len(blocks), 1)
        with open(ARGS.example) as f:
            self.assertIn(blocks[0], f.read())

if __name__ == "__main__":
    for path in (ARGS.proxima, ARGS.proximad, ARGS.example, ARGS.api_doc, ARGS.api_doc_example):
        if not os.path.exists(path):
            sys.exit(f"test_server_cli: {path} does not exist (build the tree first)")
    unittest.main(argv=[sys.argv[0], "-v", *UNITTEST_ARGS])
