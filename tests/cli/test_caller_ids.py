#!/usr/bin/env python3
"""Every id in `ccd --json` and `distance --json` is the file's own (issue #14, item 6): with and
without --split-components, on an indexed file whose vertices are interleaved between components
and which holds coincident but distinct vertices; edge-edge pairs name their vertices; --weld
merges the coincident ones (and their contacts go); `ccd --server` answers in the same ids.
Usage: test_caller_ids.py PROXIMA [PROXIMAD]."""
import json
import os
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
PROXIMAD = sys.argv[2] if len(sys.argv) > 2 else None

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, run_program  # noqa: E402

# A plane of two triangles that share no vertex index although two of their corners coincide
# (file vertices 4 = 1 and 7 = 6 in position), and a quad of two triangles (sharing an edge, so the
# file is not a triangle soup) falling through it from z = 1 to z = -1. Vertices and triangles of
# the two parts are interleaved, so a component's own numbering differs from the file's.
#   file vertex: 0 q0, 1 p0, 2 q1, 3 p1, 4 p0', 5 q2, 6 p2, 7 p2', 8 q3, 9 p3
PLANE = {1: (0, 0, 0), 3: (2, 0, 0), 4: (0, 0, 0), 6: (2, 2, 0), 7: (2, 2, 0), 9: (0, 2, 0)}
QUAD = {0: (0.5, 0.6), 2: (1.5, 0.5), 5: (1.4, 1.5), 8: (0.6, 1.4)}
TRIANGLES = [(0, 2, 5), (1, 3, 6), (0, 5, 8), (4, 7, 9)]  # quad, plane, quad, plane
DUPLICATES = {4: 1, 7: 6}  # file vertex -> the earlier vertex at the same position


def write_frame(path, z):
    verts = []
    for v in range(10):
        verts.append(PLANE[v] if v in PLANE else (*QUAD[v], z))
    with open(path, "w") as out:
        out.write(f"OFF\n{len(verts)} {len(TRIANGLES)} 0\n")
        for p in verts:
            out.write(" ".join(repr(float(c)) for c in p) + "\n")
        for t in TRIANGLES:
            out.write("3 " + " ".join(map(str, t)) + "\n")


def file_edges(welded=False):
    """The file's unique edges as sorted vertex pairs, sorted (after welding when asked)."""
    name = (lambda v: DUPLICATES.get(v, v)) if welded else (lambda v: v)
    edges = set()
    for t in TRIANGLES:
        for k in range(3):
            a, b = name(t[k]), name(t[(k + 1) % 3])
            if a != b:
                edges.add((min(a, b), max(a, b)))
    return sorted(edges)


def run_json(*args):
    r = run_program(PROXIMA, *args, "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def contact_key(p):
    """A contact in file ids, independent of which object came first."""
    mine, theirs = tuple(p["vertices"]), tuple(p["other_vertices"])
    if p["kind"] == "ee":
        return ("ee", frozenset((mine, theirs)))
    return ("vf", mine, theirs)


class CallerIds(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-ids-")
        cls.t0 = os.path.join(cls.tmp, "t0.off")
        cls.t1 = os.path.join(cls.tmp, "t1.off")
        cls.flat = os.path.join(cls.tmp, "flat.off")  # the quad lying on the plane
        write_frame(cls.t0, 1.0)
        write_frame(cls.t1, -1.0)
        write_frame(cls.flat, 0.0)

    def check_file_ids(self, doc, welded=False):
        """Every pair's ids are the file's: vf primitive = its vertex, other_primitive a file
        triangle whose corners are other_vertices; ee primitives index the file's edge list at the
        pairs named by vertices."""
        edges = file_edges(welded)
        name = (lambda v: DUPLICATES.get(v, v)) if welded else (lambda v: v)
        tris = [tuple(name(v) for v in t) for t in TRIANGLES]
        self.assertTrue(doc["pairs"])
        for p in doc["pairs"]:
            if p["kind"] == "vf":
                self.assertEqual(p["vertices"], [p["primitive"]])
                self.assertEqual(tuple(p["other_vertices"]), tris[p["other_primitive"]])
            else:
                self.assertEqual(len(p["vertices"]), 2)
                self.assertEqual(edges[p["primitive"]], tuple(p["vertices"]))
                self.assertEqual(edges[p["other_primitive"]], tuple(p["other_vertices"]))
        return {contact_key(p): p["toi"] for p in doc["pairs"]}

    def test_ccd_ids_are_the_files_with_and_without_split(self):
        whole = run_json("ccd", self.t0, self.t1)
        split = run_json("ccd", "--split-components", self.t0, self.t1)
        self.assertEqual(len(whole["objects"]), 1)
        self.assertEqual(len(split["objects"]), 3)
        a = self.check_file_ids(whole)
        b = self.check_file_ids(split)
        self.assertEqual(set(a), set(b))
        for key, toi in a.items():
            self.assertAlmostEqual(toi, b[key], delta=1e-6)
        kinds = {k[0] for k in a}
        self.assertEqual(kinds, {"vf", "ee"})
        # The quad falls through the plane at t = 0.5; the coincident but distinct corners touch
        # the other plane triangle from the start: vertex 4 (at vertex 1's place) on triangle 1.
        self.assertIn(("vf", (4,), (1, 3, 6)), a)
        self.assertEqual(a[("vf", (4,), (1, 3, 6))], 0.0)
        self.assertIn(("vf", (2,), (1, 3, 6)), a)  # quad corner 2 through plane triangle 1
        self.assertTrue(0.5 - 1e-6 <= a[("vf", (2,), (1, 3, 6))] <= 0.5)

    def test_weld_merges_coincident_vertices(self):
        welded = run_json("ccd", "--weld", self.t0, self.t1)
        a = self.check_file_ids(welded, welded=True)
        used = set()
        for key in a:
            for side in key[1:] if key[0] == "vf" else key[1]:
                used.update(side)
        self.assertFalse(used & set(DUPLICATES), "welded vertices are named by their first one")
        # The plane's triangles now share an edge: adjacent, so no contact between them.
        for key in a:
            if key[0] == "vf":
                plane_vertex = key[1][0] in PLANE
                plane_triangle = key[2][0] in PLANE
                self.assertFalse(plane_vertex and plane_triangle, key)
        split = run_json("ccd", "--weld", "--split-components", self.t0, self.t1)
        self.assertEqual(len(split["objects"]), 2)
        self.assertEqual(set(self.check_file_ids(split, welded=True)), set(a))

    def test_distance_triangle_ids_are_the_files(self):
        def pairs(doc):
            return {frozenset((c["triangle"], c["other_triangle"])) for c in doc["collisions"]}
        whole = run_json("distance", "--collisions", self.flat)
        split = run_json("distance", "--collisions", "--split-components", self.flat)
        self.assertEqual(pairs(whole), pairs(split))
        # The two plane triangles touch along the coincident diagonal: distinct vertices, so not
        # adjacent, so reported; with --weld they share the edge and are not.
        self.assertIn(frozenset((1, 3)), pairs(whole))
        welded = run_json("distance", "--collisions", "--weld", self.flat)
        self.assertNotIn(frozenset((1, 3)), pairs(welded))
        self.assertIn(frozenset((0, 1)), pairs(whole))  # the quad lying on the plane
        self.assertIn(frozenset((2, 3)), pairs(split))

    @unittest.skipUnless(PROXIMAD, "no proximad given")
    def test_ccd_on_a_daemon_names_the_same_ids(self):
        daemon = Daemon(PROXIMAD)
        try:
            local = run_json("ccd", "--split-components", self.t0, self.t1)
            remote = run_json("ccd", "--split-components", "--server", daemon.address,
                              self.t0, self.t1)
            self.assertEqual(local["pairs"], remote["pairs"])
            self.assertEqual(local["object_pairs"], remote["object_pairs"])
        finally:
            daemon.stop()
            daemon.close()


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
