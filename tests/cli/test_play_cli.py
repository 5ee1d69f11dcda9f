#!/usr/bin/env python3
"""proxima play, the recorded-sequence player (issue #19 items 2-3), against a proximad it starts:

- a numbered-OBJ sequence written here (two boxes, one moving through the other, named so that
  only natural order is right: frame_9 before frame_10): --local and --server print the same
  answers for every frame, which equal `proxima distance` and `proxima ccd` run on the same files
  one at a time, and the known gaps of the boxes;
- a breaking sequence from `proxima generate sequence` (objects break into pieces mid-stream: a
  topology change): --local and --server agree, and every frame's closest distance and collision
  count equal `proxima demo` running the same procedural scene in-process;
- one real frames pair from ../shared/data/frames (skipped, saying so, when the folder is absent);
- a Quake II MD2 model written here: its keyframes play like the same frames as OBJ files;
- errors: a missing folder, a folder without meshes, an unreadable frame, --frames out of range,
  usage errors (exit 2).
Usage: test_play_cli.py PROXIMA PROXIMAD [DATA_DIR]
"""
import json
import os
import shutil
import struct
import sys
import tempfile
import unittest

PROXIMA, PROXIMAD = sys.argv[1:3]
DATA = sys.argv[3] if len(sys.argv) > 3 else ""

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, box_mesh, run_program, write_off  # noqa: E402

# Per-frame keys that are measurements, not answers.
TIME_KEYS = {"latency_ms", "late_ms", "stats"}


def answers(lines):
    return [{k: v for k, v in d.items() if k not in TIME_KEYS} for d in lines]


def check_closest(test, got, ref_objects, where):
    """The frame's closest pair has the smallest separation distance of the one-shot answer, and
    its points are that far apart. (Where several pairs tie, at contact or between parallel
    faces, which one is reported depends on the culler's history, so the pair itself may differ.)
    """
    best = min((o["separation"] for o in ref_objects), key=lambda s: s["distance"])
    test.assertEqual(got["distance"], best["distance"], where)
    gap = sum((a - b) ** 2 for a, b in zip(got["point"], got["other_point"])) ** 0.5
    test.assertAlmostEqual(gap, got["distance"], places=9, msg=where)
    test.assertNotEqual(got["object"], got["other"], where)


def write_obj(path, parts):
    verts, faces = [], []
    for v, f in parts:
        base = len(verts)
        verts += v
        faces += [tuple(base + i for i in t) for t in f]
    with open(path, "w") as out:
        for p in verts:
            out.write("v " + " ".join(repr(float(c)) for c in p) + "\n")
        for t in faces:
            out.write("f " + " ".join(str(i + 1) for i in t) + "\n")


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def write_md2(path, triangles, keyframes):
    """A Quake II MD2 model: `keyframes` is a list of (scale, translate, [(x, y, z) bytes]).
    Returns each keyframe's positions as the reader computes them (in double)."""
    nv, nt, nf = len(keyframes[0][2]), len(triangles), len(keyframes)
    frame_size = 40 + 4 * nv
    ofs_tris = 68
    ofs_frames = ofs_tris + 12 * nt
    ofs_end = ofs_frames + nf * frame_size
    out = b"IDP2" + struct.pack("<16i", 8, 64, 64, frame_size, 0, nv, 0, nt, 0, nf, 68, 68,
                                 ofs_tris, ofs_frames, ofs_end, ofs_end)
    for t in triangles:
        out += struct.pack("<6H", *t, 0, 0, 0)
    positions = []
    for k, (scale, translate, verts) in enumerate(keyframes):
        out += struct.pack("<6f", *scale, *translate) + f"key{k}".encode().ljust(16, b"\0")
        for v in verts:
            out += struct.pack("<4B", *v, 0)
        positions.append([tuple(f32(scale[i]) * v[i] + f32(translate[i]) for i in range(3))
                          for v in verts])
    with open(path, "wb") as f:
        f.write(out)
    return positions


# The moving box's x offset per frame: approaching, touching, passing through the fixed box.
OFFSETS = [2.0, 1.6, 1.3, 1.1, 0.9, 0.5]


class Play(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-play-")
        cls.daemon = Daemon(PROXIMAD)
        # Boxes: fixed [0,1]^3 and a moving 0.5-box at x = offset (gap offset - 1 while apart).
        cls.obj_dir = os.path.join(cls.tmp, "boxes")
        os.makedirs(cls.obj_dir)
        cls.obj_files = []
        for k, x in enumerate(OFFSETS):
            # Numbers 5..10: frame_9 comes before frame_10 only in natural order.
            path = os.path.join(cls.obj_dir, f"frame_{k + 5}.obj")
            write_obj(path, [box_mesh((0, 0, 0), (1, 1, 1)),
                             box_mesh((x, 0.25, 0.25), (x + 0.5, 0.75, 0.75))])
            cls.obj_files.append(path)
        with open(os.path.join(cls.obj_dir, "README.txt"), "w") as f:
            f.write("not a frame\n")
        cls.broken_dir = os.path.join(cls.tmp, "breaking")
        p = run_program(PROXIMA, "generate", "sequence", "--scene", "breaking", "--frames", "6",
                        "--dir", cls.broken_dir, "--quiet")
        assert p.returncode == 0, p.stderr
        cls.generated = json.loads(p.stdout)

    @classmethod
    def tearDownClass(cls):
        cls.daemon.stop()
        cls.daemon.close()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def play(self, *args):
        p = run_program(PROXIMA, "play", "--json", *args)
        self.assertEqual(p.returncode, 0, f"play {args}: {p.stderr}")
        return [json.loads(x) for x in p.stdout.splitlines()]

    def play_both(self, *args):
        """--local and --server: the same answers, frame by frame."""
        local = self.play("--local", *args)
        remote = self.play("--server", self.daemon.address, *args)
        self.assertEqual(answers(remote), answers(local), f"play {args}: --server vs --local")
        self.assertTrue(all(d["latency_ms"] > 0 for d in remote))
        return local

    def test_numbered_obj_sequence(self):
        frames = self.play_both(self.obj_dir, "--split-components", "--query",
                                "separation,self,collisions,tolerance,ccd", "--tolerance", "0.25")
        self.assertEqual([d["frame"] for d in frames], list(range(len(OFFSETS))))
        self.assertEqual([d["file"] for d in frames], self.obj_files, "natural order")
        self.assertFalse(any(d["topology_change"] for d in frames))
        for d, x in zip(frames, OFFSETS):
            self.assertEqual(d["object_count"], 2)
            self.assertEqual(d["triangle_count"], 24)
            gap = max(x - 1.0, 0.0)
            self.assertAlmostEqual(d["closest"]["distance"], gap, places=12, msg=d["file"])
            self.assertEqual(d["collision_count"] > 0, x < 1.0, d["file"])
        # Each frame alone through `proxima distance` (the engine in one shot): the same answers.
        for d, path in zip(frames, self.obj_files):
            p = run_program(PROXIMA, "distance", "--json", "--split-components", "--self",
                            "--collisions", "--tolerance", "0.25", path)
            self.assertEqual(p.returncode, 0, p.stderr)
            ref = json.loads(p.stdout)
            check_closest(self, d["closest"], ref["objects"], path)
            self.assertEqual(d["collision_count"], len(ref["collisions"]), path)
            self.assertEqual(d["within_count"], len(ref["within"]), path)
            self.assertEqual(d["min_self_distance"],
                             min(s["distance"] for s in ref["self"] if s["distance"] is not None))
        # CCD between consecutive frames equals `proxima ccd` on the two files.
        self.assertIsNone(frames[0]["ccd"])
        for k in range(1, len(frames)):
            p = run_program(PROXIMA, "ccd", "--json", "--split-components", self.obj_files[k - 1],
                            self.obj_files[k])
            self.assertEqual(p.returncode, 0, p.stderr)
            ref = json.loads(p.stdout)
            got = frames[k]["ccd"]
            self.assertEqual(got["pair_count"], len(ref["pairs"]))
            if ref["earliest"] is None:
                self.assertIsNone(got["toi"])
            else:
                self.assertEqual(got["toi"], ref["earliest"]["toi"])
                self.assertEqual((got["object"], got["other"]),
                                 (ref["earliest"]["object"], ref["earliest"]["other"]))
        # The box reaches the other between frames 2 and 3 (x 1.3 -> 1.1 does not, 1.1 -> 0.9
        # does): a contact only from frame 4 on.
        self.assertIsNone(frames[3]["ccd"]["toi"])
        self.assertIsNotNone(frames[4]["ccd"]["toi"])

    def test_frames_range_and_text_output(self):
        frames = self.play(self.obj_dir, "--split-components", "--frames", "2:4")
        self.assertEqual([d["frame"] for d in frames], [2, 3])
        self.assertEqual([d["file"] for d in frames], self.obj_files[2:4])
        p = run_program(PROXIMA, "play", self.obj_dir, "--split-components", "--fps", "200")
        self.assertEqual(p.returncode, 0, p.stderr)
        lines = p.stdout.splitlines()
        self.assertIn("at 200 frames/s", lines[0])
        self.assertEqual(len(lines), 2 + len(OFFSETS) + 1, p.stdout)
        self.assertTrue(lines[-1].startswith(f"play: {len(OFFSETS)} frames (0 topology changes)"))

    def test_md2_keyframes(self):
        """An MD2 model (two tetrahedra closing in on each other over four keyframes) plays like
        the same frames written as numbered OBJ files."""
        tet = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
        triangles = tet + [tuple(i + 4 for i in t) for t in tet]
        keyframes = []
        for k in range(4):
            a = [(0, 0, 0), (20, 0, 0), (0, 20, 0), (0, 0, 20)]
            b = [(v[0] + 120 - 25 * k, v[1] + 5, v[2] + 5) for v in a]
            keyframes.append(((0.05, 0.05, 0.05), (0.25 * k, -1.0, 0.5), a + b))
        md2 = os.path.join(self.tmp, "tets.md2")
        positions = write_md2(md2, triangles, keyframes)
        obj_dir = os.path.join(self.tmp, "tets-obj")
        os.makedirs(obj_dir)
        for k, verts in enumerate(positions):
            write_obj(os.path.join(obj_dir, f"key_{k}.obj"), [(verts, triangles)])
        query = ("--split-components", "--query", "separation,self,collisions,ccd",
                 "--as-fast-as-answered")
        from_md2 = self.play_both(md2, *query)
        from_obj = self.play("--local", obj_dir, *query)
        self.assertEqual(len(from_md2), 4)
        self.assertTrue(all(d["file"] == md2 for d in from_md2))
        strip = lambda d: {k: v for k, v in d.items() if k != "file"}  # noqa: E731
        self.assertEqual([strip(d) for d in answers(from_md2)],
                         [strip(d) for d in answers(from_obj)])
        self.assertEqual([d["object_count"] for d in from_md2], [2] * 4)
        # MD2 keyframes are recorded at 10 frames/s.
        p = run_program(PROXIMA, "play", md2, "--frames", "0:2")
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("at 10 frames/s", p.stdout.splitlines()[0])
        with open(os.path.join(self.tmp, "broken.md2"), "wb") as f:
            f.write(b"IDP2" + b"\0" * 30)
        p = run_program(PROXIMA, "play", os.path.join(self.tmp, "broken.md2"))
        self.assertEqual(p.returncode, 1)
        self.assertIn("not a valid MD2 file", p.stderr)

    def test_breaking_sequence(self):
        self.assertEqual(self.generated["frame_count"], 6)
        self.assertEqual(self.generated["topology_change_count"], 1)
        frames = self.play_both(self.broken_dir, "--split-components", "--query",
                                "separation,collisions,ccd")
        self.assertEqual([d["topology_change"] for d in frames],
                         [False, False, False, True, False, False])
        # Pipelined (frames sent ahead of their answers, waiting only for the topology change's
        # new ids): the same answers.
        pipelined = self.play("--server", self.daemon.address, "--in-flight", "4",
                              self.broken_dir, "--split-components", "--query",
                              "separation,collisions,ccd")
        self.assertEqual(answers(pipelined), answers(frames))
        self.assertEqual([d["object_count"] for d in frames], [5, 5, 5, 25, 25, 25])
        # No CCD across the topology change, CCD on the others.
        self.assertEqual([d["ccd"] is None for d in frames], [True, False, False, True, False,
                                                              False])
        # The same procedural scene, run by `proxima demo` in-process: the same answers (the
        # frames are binary PLY with double coordinates, so they are bit for bit the same).
        p = run_program(PROXIMA, "demo", "--json", "--scene", "breaking", "--frames", "6")
        self.assertEqual(p.returncode, 0, p.stderr)
        demo = [json.loads(x) for x in p.stdout.splitlines()]
        for d, ref in zip(frames, demo):
            self.assertEqual(d["object_count"], ref["object_count"])
            self.assertEqual(d["triangle_count"], ref["triangle_count"])
            self.assertEqual(d["closest"]["distance"], ref["min_separation"], d["file"])
            self.assertEqual(d["collision_count"], ref["collision_count"], d["file"])
        # Objects are named from sequence.json; the recorded rate is used unless told otherwise.
        with open(os.path.join(self.broken_dir, "sequence.json")) as f:
            seq = json.load(f)
        self.assertEqual(seq["fps"], 30)
        self.assertEqual(seq["frames"][3]["objects"][:2], ["ball0.piece0", "ball0.piece1"])
        p = run_program(PROXIMA, "play", self.broken_dir, "--split-components", "--frames", "0:2")
        self.assertIn("at 30 frames/s", p.stdout.splitlines()[0])

    def test_real_frames_pair(self):
        folder = os.path.join(DATA, "frames", "cloth-funnel") if DATA else ""
        if not folder or not os.path.isdir(folder):
            self.skipTest(f"no ../shared/data/frames/cloth-funnel (data dir '{DATA}')")
        frames = self.play_both(folder, "--split-components", "--query",
                                "separation,collisions,tolerance", "--tolerance", "0.002")
        self.assertEqual(len(frames), 2)
        self.assertFalse(frames[1]["topology_change"])
        for d in frames:
            p = run_program(PROXIMA, "distance", "--json", "--split-components", "--collisions",
                            "--tolerance", "0.002", d["file"])
            self.assertEqual(p.returncode, 0, p.stderr)
            ref = json.loads(p.stdout)
            self.assertEqual(d["object_count"], len(ref["objects"]))
            check_closest(self, d["closest"], ref["objects"], d["file"])
            self.assertEqual(d["collision_count"], len(ref["collisions"]))
            self.assertEqual(d["within_count"], len(ref["within"]))

    def test_errors(self):
        def fails(code, *args, says=""):
            p = run_program(PROXIMA, "play", *args)
            self.assertEqual(p.returncode, code, f"{args}: {p.stdout} {p.stderr}")
            self.assertIn("error", p.stderr)
            self.assertIn(says, p.stderr)
            self.assertNotIn("Traceback", p.stderr)
            return p
        fails(1, os.path.join(self.tmp, "absent"), says="does not exist")
        empty = os.path.join(self.tmp, "empty")
        os.makedirs(empty, exist_ok=True)
        with open(os.path.join(empty, "notes.txt"), "w") as f:
            f.write("x\n")
        fails(1, empty, says="holds no mesh files")
        bad = os.path.join(self.tmp, "bad")
        os.makedirs(bad, exist_ok=True)
        shutil.copy(self.obj_files[0], os.path.join(bad, "frame_0.obj"))
        with open(os.path.join(bad, "frame_1.obj"), "w") as f:
            f.write("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
        fails(1, bad, says="frame_1.obj")
        fails(1, self.obj_dir, "--frames", "7:9", says="selects no frame")
        fails(2, self.obj_dir, "--frames", "x")
        fails(2, self.obj_dir, "--query", "tolerance", says="--tolerance")
        fails(2, self.obj_dir, "--query", "separation,volume")
        fails(2, self.obj_dir, "--fps", "10", "--as-fast-as-answered")
        fails(2, self.obj_dir, "--in-flight", "4")  # needs --server
        fails(1, self.obj_dir, "--server", "127.0.0.1:1", says="UNAVAILABLE")


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
