#!/usr/bin/env python3
"""Tests of `proxima` as a user runs it: the JSON contract, exit codes and error messages on bad
input (never a crash), and agreement between cullers. Usage: test_cli.py PROXIMA [DATA_DIR]."""
import json
import math
import os
import subprocess
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
DATA = sys.argv[2] if len(sys.argv) > 2 else ""

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import box_mesh, run_program, strip_stats, write_off  # noqa: E402


def run(*args):
    return run_program(PROXIMA, *args)


class Cli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-cli-")
        cls.a = os.path.join(cls.tmp, "a.off")
        cls.b = os.path.join(cls.tmp, "b.off")
        cls.two = os.path.join(cls.tmp, "two.off")
        write_off(cls.a, [box_mesh((0, 0, 0), (1, 1, 1))])
        write_off(cls.b, [box_mesh((1.5, 0, 0), (2.5, 1, 1))])
        write_off(cls.two, [box_mesh((0, 0, 0), (1, 1, 1)), box_mesh((0, 0, 1.25), (1, 1, 2))])

    def tmpfile(self, name, text):
        path = os.path.join(self.tmp, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def distance(self, *args):
        p = run("distance", "--local", "--json", *args)
        self.assertEqual(p.returncode, 0, p.stderr)
        return json.loads(p.stdout)

    def test_separation_contract(self):
        doc = self.distance(self.a, self.b)
        self.assertEqual(len(doc["objects"]), 2)
        for i, o in enumerate(doc["objects"]):
            s = o["separation"]
            self.assertEqual(set(s), {"object", "triangle", "point", "other", "other_triangle",
                                      "other_point", "distance"})
            self.assertEqual(s["object"], i)
            self.assertAlmostEqual(s["distance"], 0.5, places=12)
            self.assertEqual(s["other"], 1 - i)
            self.assertEqual(len(s["point"]), 3)
            self.assertAlmostEqual(math.dist(s["point"], s["other_point"]), 0.5, places=12)
            self.assertTrue(0 <= s["triangle"] < 12 and 0 <= s["other_triangle"] < 12)
        self.assertIn("stats", doc)
        self.assertGreater(doc["stats"]["exact_tests"], 0)
        # Separation alone: brute force tests the 12 x 12 triangle pairs of the one object pair.
        self.assertEqual(doc["stats"]["brute_force_tests"], 144)
        # With self too, each box's non-adjacent pairs as well; the brute culler tests exactly that.
        doc = self.distance("--self", "--culler", "brute", self.a, self.b)
        self.assertEqual(doc["stats"]["brute_force_tests"], 144 + 2 * (66 - self.ring_pairs()))
        self.assertEqual(doc["stats"]["exact_tests"], doc["stats"]["brute_force_tests"])

    @staticmethod
    def ring_pairs():
        # Adjacent (vertex-sharing) unordered triangle pairs of the 12-triangle box.
        _, f = box_mesh((0, 0, 0), (1, 1, 1))
        return sum(1 for i in range(12) for j in range(i + 1, 12) if set(f[i]) & set(f[j]))

    def test_gzip_compressed_files_answer_like_the_plain_ones(self):
        import gzip
        packed = [os.path.join(self.tmp, os.path.basename(p) + ".gz") for p in (self.a, self.two)]
        for src, dst in zip((self.a, self.two), packed):
            with open(src, "rb") as f, gzip.open(dst, "wb") as out:
                out.write(f.read())
        plain = self.distance("--split-components", "--self", self.a, self.two)
        compressed = self.distance("--split-components", "--self", *packed)
        self.assertEqual(strip_stats(compressed, ("objects",)), strip_stats(plain, ("objects",)))
        for p, c in zip(plain["objects"], compressed["objects"]):
            self.assertEqual({k: v for k, v in c.items() if k not in ("file", "name")},
                             {k: v for k, v in p.items() if k not in ("file", "name")})
        # Corrupt data is bad input (exit 1) naming the file, not a crash.
        broken = os.path.join(self.tmp, "broken.off.gz")
        with open(broken, "wb") as f:
            f.write(b"\x1f\x8b" + b"\x00" * 40)
        p = run("distance", broken)
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("broken.off.gz", p.stderr)
        self.assertIn("gzip data", p.stderr)

    def test_split_components_and_file_triangle_ids(self):
        doc = self.distance("--split-components", self.two)
        self.assertEqual(len(doc["objects"]), 2)
        s0 = doc["objects"][0]["separation"]
        s1 = doc["objects"][1]["separation"]
        self.assertAlmostEqual(s0["distance"], 0.25, places=12)
        self.assertEqual(s0["other"], 1)
        # Triangle ids are indices in the input file: component 1 holds triangles 12..23.
        self.assertTrue(0 <= s0["triangle"] < 12 and 12 <= s0["other_triangle"] < 24)
        self.assertTrue(12 <= s1["triangle"] < 24 and 0 <= s1["other_triangle"] < 12)

    def test_single_object_has_no_separation(self):
        doc = self.distance(self.a)
        self.assertIsNone(doc["objects"][0]["separation"]["distance"])
        self.assertIsNone(doc["objects"][0]["separation"]["other"])

    def test_self_collisions_tolerance(self):
        doc = self.distance("--self", "--collisions", "--tolerance", "0.3", "--split-components",
                            self.two)
        self.assertEqual(len(doc["self"]), 24)
        for e in doc["self"]:
            self.assertEqual(set(e), {"object", "triangle", "closest", "distance"})
        self.assertEqual(doc["collisions"], [])
        # Opposite faces of a unit box are 1 apart: nothing within 0.3 inside one box; the boxes
        # are 0.25 apart, so some inter-object pairs are within.
        self.assertTrue(all(p["object"] != p["other"] for p in doc["within"]))
        self.assertGreater(len(doc["within"]), 0)

    def test_crossing_boxes_collide(self):
        c = os.path.join(self.tmp, "c.off")
        write_off(c, [box_mesh((0.5, 0.5, 0.5), (1.5, 1.5, 1.5))])
        doc = self.distance("--collisions", self.a, c)
        self.assertGreater(len(doc["collisions"]), 0)
        for p in doc["collisions"]:
            self.assertEqual(set(p), {"object", "triangle", "other", "other_triangle"})
        self.assertEqual(doc["objects"][0]["separation"]["distance"], 0.0)

    def test_penetration_of_overlapping_boxes(self):
        # b overlaps a by 0.3 along x: the local penetration vector is (-0.3, 0, 0) for a.
        c = os.path.join(self.tmp, "over.off")
        write_off(c, [box_mesh((0.7, 0.2, 0.2), (1.7, 0.8, 0.8))])
        doc = self.distance("--penetration", self.a, c)
        self.assertGreater(len(doc["collisions"]), 0)  # --penetration implies --collisions
        self.assertEqual(len(doc["penetrations"]), 1)
        p = doc["penetrations"][0]
        self.assertEqual((p["object"], p["other"]), (0, 1))
        self.assertAlmostEqual(p["depth"], 0.3, places=9)
        for got, want in zip(p["direction"], (-1.0, 0.0, 0.0)):
            self.assertAlmostEqual(got, want, places=9)
        self.assertTrue(p["isolated"])
        self.assertTrue(p["closed"])
        self.assertEqual(self.distance("--penetration", self.a, self.b)["penetrations"], [])

    def test_cullers_agree(self):
        args = ["--self", "--collisions", "--tolerance", "0.3", "--split-components", self.two,
                self.a, self.b]
        brute = strip_stats(self.distance("--culler", "brute", *args))
        bvh = strip_stats(self.distance("--culler", "bvh", *args))
        for x, y in zip(brute["objects"], bvh["objects"]):
            self.assertAlmostEqual(x["separation"]["distance"], y["separation"]["distance"], places=12)
        self.assertEqual([e["distance"] for e in brute["self"]], [e["distance"] for e in bvh["self"]])
        self.assertEqual(brute["collisions"], bvh["collisions"])
        self.assertEqual(brute["within"], bvh["within"])

    def expect_error(self, *args, words=()):
        p = run("distance", "--local", "--json", *args)
        self.assertNotEqual(p.returncode, 0, p.stdout)
        self.assertEqual(p.stdout.strip(), "")
        self.assertIn("error", p.stderr)
        for w in words:
            self.assertIn(w, p.stderr)
        return p

    def test_bad_input(self):
        missing = os.path.join(self.tmp, "nope.off")
        self.expect_error(missing, words=("nope.off", "no such file"))
        bad_index = self.tmpfile("bad_index.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
        self.expect_error(bad_index, words=("bad_index.off", "7"))
        nan = self.tmpfile("nan.off", "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n")
        self.expect_error(nan, words=("nan.off",))
        empty = self.tmpfile("empty.off", "")
        self.expect_error(empty, words=("empty.off",))
        garbage = os.path.join(self.tmp, "garbage.ply")
        with open(garbage, "wb") as f:
            f.write(b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
                    b"property float x\nproperty float y\nproperty float z\nend_header\n\x00\x01")
        self.expect_error(garbage, words=("garbage.ply",))
        self.expect_error(self.tmp, words=(self.tmp,))
        p = run("distance", "--local", "--tolerance", "-1", self.a)
        self.assertNotEqual(p.returncode, 0)
        p = run("distance", "--local", "--culler", "magic", self.a)
        self.assertNotEqual(p.returncode, 0)

    def test_real_frames(self):
        path = os.path.join(DATA, "frames", "armadillo-rollers", "326.ply")
        if not os.path.exists(path):
            self.skipTest(f"data set absent: {path}")
        doc = self.distance("--split-components", path)
        self.assertGreaterEqual(len(doc["objects"]), 2)
        for o in doc["objects"]:
            self.assertIsNotNone(o["separation"]["distance"])
            self.assertGreaterEqual(o["separation"]["distance"], 0.0)

    def test_demo(self):
        p = run("demo", "--frames", "3", "--scene", "bowl", "--json")
        self.assertEqual(p.returncode, 0, p.stderr)
        lines = [json.loads(x) for x in p.stdout.splitlines()]
        self.assertEqual([x["frame"] for x in lines], [0, 1, 2])
        self.assertGreater(lines[0]["object_count"], 1)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
