#!/usr/bin/env python3
"""Tests of `proxima ccd` as a user runs it: two frames as OFF files with known contacts, the JSON
shape, text output, and exit codes with messages on bad input (never a crash).
Usage: test_ccd_cli.py PROXIMA."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
TOL = 1e-6  # the elementary tests' default tolerance: a toi is in [true - TOL, true]

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import run_program, write_off  # noqa: E402


def run(*args):
    return run_program(PROXIMA, *args, timeout=100)


def plane(z=0.0):
    return [(0, 0, z), (2, 0, z), (2, 2, z), (0, 2, z)], [(0, 1, 2), (0, 2, 3)]


def small_triangle(z):
    return [(0.5, 0.5, z), (1.5, 0.6, z), (0.7, 1.4, z)], [(0, 1, 2)]


class CcdCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-ccd-cli-")
        p = lambda name: os.path.join(cls.tmp, name)
        # A triangle falling from z = 1 to z = -1 through a static plane: contact at t = 0.5.
        cls.drop0, cls.drop1 = p("drop0.off"), p("drop1.off")
        write_off(cls.drop0, [plane(), small_triangle(1.0)])
        write_off(cls.drop1, [plane(), small_triangle(-1.0)])
        # Two edges crossing at t = 0.5 (and nothing else touching): a triangle hanging below its
        # top edge (0,0,0)-(1,0,0) in the plane y = 0, and one standing on its bottom edge in the
        # plane x = 0.5, moving down by 1 from height 0.5.
        hang = ([(0, 0, 0), (1, 0, 0), (0.5, 0, -1)], [(0, 1, 2)])
        stand = lambda z: ([(0.5, -0.5, z), (0.5, 0.5, z), (0.5, 0, z + 1)], [(0, 1, 2)])
        cls.cross0, cls.cross1 = p("cross0.off"), p("cross1.off")
        write_off(cls.cross0, [hang, stand(0.5)])
        write_off(cls.cross1, [hang, stand(-0.5)])
        # Far apart and static: nothing.
        cls.apart = p("apart.off")
        write_off(cls.apart, [plane(), small_triangle(1.0)])
        # Not the same topology as drop0: one triangle fewer.
        cls.other = p("other.off")
        write_off(cls.other, [plane()])

    def ccd_json(self, *args):
        r = run("ccd", "--json", *args)
        self.assertEqual(r.returncode, 0, r.stderr)
        return json.loads(r.stdout)

    def check_shape(self, doc):
        for key in ("objects", "pairs", "object_pairs", "earliest", "stats"):
            self.assertIn(key, doc)
        for p in doc["pairs"]:
            for key in ("kind", "object", "primitive", "other", "other_primitive", "vertices", "other_vertices", "toi"):
                self.assertIn(key, p)
            self.assertIn(p["kind"], ("vf", "ee"))
            self.assertTrue(0.0 <= p["toi"] <= 1.0)
        for key in ("candidate_pairs", "elementary_tests", "capped_tests",
                    "broad_phase_seconds", "narrow_phase_seconds", "total_seconds"):
            self.assertIn(key, doc["stats"])
        if doc["pairs"]:
            self.assertEqual(doc["earliest"]["toi"], min(p["toi"] for p in doc["pairs"]))
            for op in doc["object_pairs"]:
                self.assertEqual(set(op), {"object", "other", "toi", "pair"})
                self.assertLessEqual(op["object"], op["other"])
                contact = doc["pairs"][op["pair"]]
                self.assertEqual(sorted((contact["object"], contact["other"])),
                                 [op["object"], op["other"]])
                self.assertEqual(contact["toi"], op["toi"])
                self.assertEqual(op["toi"], min(
                    p["toi"] for p in doc["pairs"]
                    if sorted((p["object"], p["other"])) == [op["object"], op["other"]]))
        else:
            self.assertIsNone(doc["earliest"])

    def test_vertex_through_plane_between_objects(self):
        doc = self.ccd_json("--local", "--split-components", self.drop0, self.drop1)
        self.check_shape(doc)
        self.assertEqual(len(doc["objects"]), 2)
        self.assertGreaterEqual(len(doc["pairs"]), 3)
        e = doc["earliest"]
        self.assertTrue(0.5 - TOL <= e["toi"] <= 0.5, e)
        # Each of the three falling vertices (object 1: file vertices 4, 5, 6 after the plane's
        # four; ids are the file's, also with --split-components) meets the plane (object 0).
        hit = {p["primitive"] for p in doc["pairs"]
               if p["kind"] == "vf" and p["object"] == 1 and p["other"] == 0}
        self.assertEqual(hit, {4, 5, 6})
        self.assertEqual([(o["object"], o["other"]) for o in doc["object_pairs"]], [(0, 1)])

    def test_one_object_self_contacts(self):
        # Without --split-components the file is one object: the same contacts are self pairs.
        doc = self.ccd_json(self.drop0, self.drop1)
        self.check_shape(doc)
        self.assertEqual(len(doc["objects"]), 1)
        self.assertTrue(0.5 - TOL <= doc["earliest"]["toi"] <= 0.5)
        self.assertEqual([(o["object"], o["other"]) for o in doc["object_pairs"]], [(0, 0)])

    def test_two_crossing_edges(self):
        doc = self.ccd_json("--split-components", self.cross0, self.cross1)
        self.check_shape(doc)
        self.assertEqual(len(doc["pairs"]), 1, doc["pairs"])
        p = doc["pairs"][0]
        self.assertEqual((p["kind"], p["object"], p["other"]), ("ee", 0, 1))
        # Edge indices are the file's: its sorted unique vertex pairs are (0,1), (0,2), (1,2) of
        # the hanging triangle, then (3,4), (3,5), (4,5) of the standing one; its bottom edge is
        # (3, 4), file edge 3. The pair names both edges' vertices.
        self.assertEqual((p["primitive"], p["other_primitive"]), (0, 3))
        self.assertEqual((p["vertices"], p["other_vertices"]), ([0, 1], [3, 4]))
        self.assertTrue(0.5 - TOL <= p["toi"] <= 0.5)

    def test_min_distance(self):
        # Static frames: nothing, unless the minimum distance reaches the gap (1 between the
        # plane and the triangle).
        doc = self.ccd_json("--split-components", self.apart, self.apart)
        self.assertEqual(doc["pairs"], [])
        self.assertIsNone(doc["earliest"])
        doc = self.ccd_json("--split-components", "--min-distance", "1.5", self.apart, self.apart)
        self.check_shape(doc)
        self.assertEqual(doc["earliest"]["toi"], 0.0)

    def test_text_output(self):
        r = run("ccd", "--split-components", self.drop0, self.drop1)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("earliest: toi", r.stdout)
        self.assertIn("elementary tests", r.stdout)
        r = run("ccd", self.apart, self.apart)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("no contact", r.stdout)

    def test_different_topology_is_an_error(self):
        r = run("ccd", "--json", self.drop0, self.other)
        self.assertEqual(r.returncode, 1)
        self.assertIn("same topology", r.stderr)
        self.assertEqual(r.stdout, "")
        r = run("ccd", "--split-components", self.drop0, self.other)
        self.assertEqual(r.returncode, 1)
        self.assertIn("2 objects at t0, 1 at t1", r.stderr)

    def test_bad_input(self):
        r = run("ccd", "--json", self.drop0, os.path.join(self.tmp, "missing.off"))
        self.assertEqual(r.returncode, 1)
        self.assertIn("missing.off", r.stderr)
        r = run("ccd", self.drop0)  # one file
        self.assertNotEqual(r.returncode, 0)
        r = run("ccd", "--min-distance", "-1", self.drop0, self.drop1)
        self.assertNotEqual(r.returncode, 0)
        # No daemon there: exit 1 with the reason (server mode is tested in tests/clients).
        r = run("ccd", "--server", "127.0.0.1:1", self.drop0, self.drop1)
        self.assertEqual(r.returncode, 1)
        self.assertIn("proxima: error:", r.stderr)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0]])
