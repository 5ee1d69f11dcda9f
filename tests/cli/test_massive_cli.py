#!/usr/bin/env python3
"""Tests of `proxima verify` and `proxima review` as a user runs them, on a small store imported
from OFF files: `verify --store` equals `verify --store --brute-force` exactly (every pair, every
double), `review --store` on a tiny path gives the expected contacts and latency percentiles, bad
path files are exit 1 with a message; with PROXIMAD given, the same commands on the daemon
(`--server`) print the same answers and `proxima models` lists the store.
Usage: test_massive_cli.py PROXIMA [PROXIMAD]."""
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

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
PROXIMAD = sys.argv[2] if len(sys.argv) > 2 else None

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, box_mesh, write_off
from cli_helpers import run_program as run  # noqa: E402


def grid(n, x0, y0, z, size):
    """A flat n x n grid of squares (2 n^2 triangles): large enough to be split into pieces."""
    v = [(x0 + size * i / n, y0 + size * j / n, z) for j in range(n + 1) for i in range(n + 1)]
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    return v, f


def write_off_one(path, mesh):
    write_off(path, [mesh])


def strip_stats(doc):
    """The answer without statistics, timings and where it ran."""
    doc = {k: v for k, v in doc.items()
           if k not in ("stats", "latency_ms", "cache", "server", "store", "model", "room",
                        "member", "peer_updates", "edits_seen", "method")}
    if "poses" in doc:
        doc["poses"] = [{k: v for k, v in p.items() if k not in ("stats", "model_version")}
                        for p in doc["poses"]]
    return doc


class MassiveCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-massive-cli-")
        meshes = os.path.join(cls.tmp, "meshes")
        os.makedirs(meshes)
        # A row of boxes 1 apart, pairs touching (0-1), 0.05 apart (2-3) and overlapping (4-5),
        # and a fine floor grid under them, touching every box.
        shift = [0.0, -1.0, 0.0, -0.95, 0.0, -1.3]
        for i in range(6):
            x = 2.0 * i + shift[i]
            write_off_one(os.path.join(meshes, f"box-{i}.off"),
                          box_mesh((x, 0, 0), (x + 1, 1, 1)))
        write_off_one(os.path.join(meshes, "floor.off"), grid(40, -1, -1, 0.0, 14))
        cls.models = os.path.join(cls.tmp, "models")
        cls.store = os.path.join(cls.models, "row")
        p = run(PROXIMA, "import", "--store", cls.store, "--max-piece-bytes", "64K", "--quiet",
                meshes)
        assert p.returncode == 0, p.stderr
        cls.summary = json.loads(p.stdout)
        cls.avatar = os.path.join(cls.tmp, "avatar.off")
        write_off_one(cls.avatar, box_mesh((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1)))
        cls.path = os.path.join(cls.tmp, "path.txt")
        with open(cls.path, "w") as out:
            out.write("# along the row at mid height, then one full transform\n")
            for k in range(12):
                out.write(f"{0.5 + k}, 0.5, 0.5\n")
            out.write("\n1 0 0 1.0  0 1 0 0.5  0 0 1 0.5\n")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def json_of(self, *args):
        p = run(PROXIMA, *args)
        self.assertEqual(p.returncode, 0, f"{args}: {p.stderr}")
        return json.loads(p.stdout)

    def test_store_is_split(self):
        self.assertEqual(self.summary["object_count"], 7)
        self.assertGreater(self.summary["piece_count"], 7)

    def test_verify_equals_brute_force(self):
        for tolerance in ("0", "0.1"):
            static = self.json_of("verify", "--store", self.store, "--tolerance", tolerance,
                                  "--cache-bytes", "256K", "--quiet")
            brute = self.json_of("verify", "--store", self.store, "--tolerance", tolerance,
                                 "--brute-force", "--quiet")
            self.assertEqual(static["method"], "static")
            self.assertEqual(brute["method"], "brute-force")
            # Exact: the same pairs, names, triangles and doubles.
            self.assertEqual(static["pairs"], brute["pairs"], tolerance)
            self.assertGreater(len(static["pairs"]), 0)
            self.assertEqual(static["stats"]["pair_count"], len(static["pairs"]))
            names = {(p["name"], p["other_name"]) for p in static["pairs"]}
            self.assertTrue(any("floor" in a + b for a, b in names))
            if tolerance == "0.1":
                self.assertTrue(any(p["distance"] > 0 for p in static["pairs"]))
            else:
                self.assertTrue(all(p["distance"] == 0 for p in static["pairs"]))

    def test_verify_progress_and_json_file(self):
        out = os.path.join(self.tmp, "verify.json")
        p = run(PROXIMA, "verify", "--store", self.store, "--tolerance", "0.1", "--out", out)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(p.stdout, "")
        self.assertIn("verifying", p.stderr)
        with open(out) as f:
            doc = json.load(f)
        self.assertIn("pairs", doc)
        q = run(PROXIMA, "verify", "--store", self.store, "--tolerance", "0.1", "--quiet")
        self.assertEqual(q.stderr, "")

    def test_review_local(self):
        doc = self.json_of("review", "--store", self.store, "--avatar", self.avatar, "--path",
                           self.path, "--tolerance", "0.2", "--quiet")
        poses = doc["poses"]
        self.assertEqual(len(poses), 13)
        self.assertEqual([p["sequence"] for p in poses], list(range(1, 14)))
        # x = 0.5 is inside box-0 (surfaces 0.4 away); x = 1.0 straddles the box-0/box-1 faces.
        first, last = poses[0], poses[-1]
        self.assertEqual(first["collisions"], [])
        self.assertIsNotNone(first["nearest"])
        self.assertEqual({h["name"] for h in last["collisions"]}, {"box-0.off", "box-1.off"})
        for p in poses:
            for h in p["collisions"]:
                self.assertEqual(h["distance"], 0.0)
            for h in p["within"]:
                self.assertLessEqual(h["distance"], 0.2)
        lat = doc["latency_ms"]
        self.assertEqual(lat["pose_count"], 13)
        self.assertLessEqual(lat["p50"], lat["p99"])
        self.assertLessEqual(lat["p99"], lat["max"])

    def test_bad_input(self):
        bad = os.path.join(self.tmp, "bad-path.txt")
        with open(bad, "w") as out:
            out.write("1 2 3\n1 2\n")
        p = run(PROXIMA, "review", "--store", self.store, "--avatar", self.avatar, "--path", bad)
        self.assertEqual(p.returncode, 1)
        self.assertIn("bad-path.txt:2: expected 12 numbers", p.stderr)
        p = run(PROXIMA, "verify", "--store", os.path.join(self.tmp, "nothing"), "--tolerance",
                "0")
        self.assertEqual(p.returncode, 1)
        self.assertIn("proxima: error: NOT_FOUND", p.stderr)
        # Usage errors (issue #18): exit 2, one line and the subcommand's --help.
        p = run(PROXIMA, "verify", "--tolerance", "0")
        self.assertEqual(p.returncode, 2)
        self.assertIn("--store DIR or --server ADDR", p.stderr)
        self.assertIn("Run 'proxima verify --help'", p.stderr)
        p = run(PROXIMA, "verify", "--store", self.store, "--tolerance", "0", "--cache-bytes",
                "lots")
        self.assertEqual(p.returncode, 2)
        self.assertIn("--cache-bytes: expected a positive number", p.stderr)

    @unittest.skipUnless(PROXIMAD, "no proximad given")
    def test_reimport_over_a_served_model_is_said(self):
        # Issue #18: re-importing replaced a served model without a word.
        models = os.path.join(self.tmp, "reimport")
        store = os.path.join(models, "box")
        box = os.path.join(self.tmp, "one-box.off")
        write_off_one(box, box_mesh((0, 0, 0), (1, 1, 1)))
        first = run(PROXIMA, "import", "--store", store, "--quiet", box)
        self.assertEqual(first.returncode, 0, first.stderr)
        self.assertNotIn("replacing", first.stderr)
        generation = json.loads(first.stdout)["generation"]
        daemon = Daemon(PROXIMAD, "--models", models, "--gpu", "off")
        try:
            self.assertEqual(run(PROXIMA, "models", "--server", daemon.address).returncode, 0)
            again = run(PROXIMA, "import", "--store", store, "--quiet", box)
            self.assertEqual(again.returncode, 0, again.stderr)
            self.assertIn(f"replacing generation {generation} of {store}", again.stderr)
            self.assertIn("switches to the new one at its next rescan", again.stderr)
            doc = json.loads(again.stdout)
            self.assertEqual(doc["replaced_generation"], generation)
            self.assertNotEqual(doc["generation"], generation)
            # Listing rescans: the daemon logs the switch, both generations named.
            self.assertEqual(run(PROXIMA, "models", "--server", daemon.address).returncode, 0)
        finally:
            daemon.stop()
            log = daemon.log()
            daemon.close()
        self.assertIn(f"model switched name=box from_generation={generation} "
                      f"to_generation={doc['generation']}", log)

    @unittest.skipUnless(PROXIMAD, "no proximad given")
    def test_server_equals_local(self):
        daemon = Daemon(PROXIMAD, "--models", self.models, "--cache-bytes", str(256 * 1024),
                        "--gpu", "off", "--log-level", "warn")
        address = daemon.address
        try:
            models = self.json_of("models", "--server", address, "--json")
            self.assertEqual([m["name"] for m in models["models"]], ["row"])
            self.assertEqual(models["models"][0]["piece_count"], self.summary["piece_count"])
            text = run(PROXIMA, "models", "--server", address)
            self.assertIn("row", text.stdout)
            local = self.json_of("verify", "--store", self.store, "--tolerance", "0.1",
                                 "--brute-force", "--quiet")
            remote = self.json_of("verify", "--server", address, "--model", "row",
                                  "--tolerance", "0.1", "--quiet")
            self.assertEqual(remote["pairs"], local["pairs"])
            local = self.json_of("review", "--store", self.store, "--avatar", self.avatar,
                                 "--path", self.path, "--tolerance", "0.2", "--quiet")
            remote = self.json_of("review", "--server", address, "--model", "row", "--avatar",
                                  self.avatar, "--path", self.path, "--tolerance", "0.2",
                                  "--room", "cli", "--member", "tester", "--quiet")
            self.assertEqual(strip_stats(remote), strip_stats(local))
            self.assertEqual(remote["room"], "cli")
            self.assertEqual(remote["latency_ms"]["pose_count"], 13)
            # Without --member: a name of its own (USER@HOST-PID), so two reviewers never clash.
            unnamed = self.json_of("review", "--server", address, "--model", "row", "--avatar",
                                   self.avatar, "--path", self.path, "--room", "cli", "--quiet")
            self.assertRegex(unnamed["member"], r"^[^@]+@[^@]+-\d+$")
            p = run(PROXIMA, "verify", "--server", address, "--model", "nope", "--tolerance", "0")
            self.assertEqual(p.returncode, 1)
            self.assertIn("NOT_FOUND", p.stderr)
            # proxima region: the whole model into an OBJ (every stored triangle once), then
            # the pieces near box 0, nearest first.
            obj = os.path.join(self.tmp, "region.obj")
            whole = self.json_of("region", "--server", address, "--model", "row", "--float64",
                                 "--obj", obj, "--quiet")
            self.assertEqual(whole["piece_count"], self.summary["piece_count"])
            self.assertEqual(whole["triangle_count"], self.summary["triangle_count"])
            self.assertFalse(whole["truncated"])
            with open(obj) as f:
                lines = f.read().splitlines()
            faces = [line for line in lines if line.startswith("f ")]
            vertices = [line for line in lines if line.startswith("v ")]
            self.assertEqual(len(faces), whole["triangle_count"])
            self.assertEqual(len(vertices), sum(p["vertex_count"] for p in whole["pieces"]))
            self.assertEqual(sum(line.startswith("o ") for line in lines), whole["piece_count"])
            top = max(int(i) for line in faces for i in line.split()[1:])
            self.assertEqual(top, len(vertices))
            ids = [line.split()[2:] for line in lines if line.startswith("# triangle_ids")]
            self.assertEqual(sum(len(i) for i in ids), whole["triangle_count"])
            near = self.json_of("region", "--server", address, "--model", "row", "--center",
                                "0.5,0.5,0.5", "--radius", "1.2", "--quiet")
            distances = [p["distance"] for p in near["pieces"]]
            self.assertEqual(distances, sorted(distances))
            self.assertTrue(0 < len(distances) < whole["piece_count"])
            self.assertTrue(all(d <= 1.2 for d in distances))
            self.assertEqual(near["pieces"][0]["name"].split("/")[-1], "box-0.off")
            p = run(PROXIMA, "region", "--server", address, "--model", "row", "--objects", "99")
            self.assertEqual(p.returncode, 1)
            self.assertIn("INVALID_ARGUMENT", p.stderr)
        finally:
            self.assertEqual(daemon.stop(), 0, daemon.log())
            daemon.close()


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0]], verbosity=2)
