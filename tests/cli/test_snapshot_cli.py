#!/usr/bin/env python3
"""Tests of `proxima snapshot` as a user runs it: a PNG of the asked size and one summary line,
`--server` writes the same bytes as local mode (same renderer: llvmpipe in CI), and bad input is
a usage error (exit 2) or a message with exit 1, never a crash. The pixels of scene snapshots are
checked by tests/engine/render/test_snapshot.cpp; those of a massive model's region
(`--server ADDR --model NAME`) here, on a small store imported from generated boxes.
Usage: test_snapshot_cli.py PROXIMA [PROXIMAD]."""
import os
import struct
import sys
import tempfile
import unittest
import zlib

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
PROXIMAD = sys.argv[2] if len(sys.argv) > 2 else None

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, box_mesh, run_program, write_off  # noqa: E402

ENV = {"MESA_SHADER_CACHE_DISABLE": "true"}


def run(*args):
    return run_program(PROXIMA, *args, timeout=100, env=ENV)


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n", head[:8]
    assert head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def png_pixels(path):
    """(width, height, rows of (r, g, b)) of an 8-bit RGB, non-interlaced PNG (what snapshots
    write), its filters undone."""
    with open(path, "rb") as f:
        data = f.read()
    pos, idat, width, height = 8, b"", 0, 0
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert (depth, colour, interlace) == (8, 2, 0), (depth, colour, interlace)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw, stride, rows, prev = zlib.decompress(idat), width * 3, [], bytearray(width * 3)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - 3] if i >= 3 else 0
            b, c = prev[i], (prev[i - 3] if i >= 3 else 0)
            if kind == 1:
                line[i] = (line[i] + a) & 255
            elif kind == 2:
                line[i] = (line[i] + b) & 255
            elif kind == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append([tuple(line[3 * x:3 * x + 3]) for x in range(width)])
        prev = line
    return width, height, rows


RED, GREY, WHITE = (220, 30, 30), (170, 170, 170), (255, 255, 255)


def shade_of(pixel, colour):
    """Flat shading with a headlight scales the colour by the facing cosine (1 when the face
    looks at the camera): the pixel is a multiple of `colour`."""
    scale = max(pixel) / max(colour)
    return scale > 0.5 and all(abs(p - c * scale) <= 3 for p, c in zip(pixel, colour))


class SnapshotCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-snapshot-cli-")
        cls.scene = os.path.join(cls.tmp, "boxes.off")
        # Two intersecting boxes and one far away.
        write_off(cls.scene, [box_mesh((0, 0, 0), (1, 1, 1)),
                              box_mesh((0.5, 0.2, 0.2), (1.5, 0.8, 0.8)),
                              box_mesh((4, 0, 0), (5, 1, 1))])

    def out(self, name):
        return os.path.join(self.tmp, name)

    def local(self, name, *args):
        r = run("snapshot", "--split-components", "--out", self.out(name), *args, self.scene)
        if r.returncode == 1 and "UNAVAILABLE" in r.stderr and not os.environ.get("CI"):
            self.skipTest(f"no EGL context here: {r.stderr.strip()}")
        self.assertEqual(r.returncode, 0, r.stderr)
        return r

    def test_local_png_and_summary(self):
        r = self.local("local.png", "--width", "64", "--height", "48", "--tolerance", "0.01")
        self.assertEqual(png_size(self.out("local.png")), (64, 48))
        self.assertEqual(r.stdout, "")
        lines = r.stderr.strip().splitlines()
        self.assertEqual(len(lines), 1, r.stderr)
        self.assertTrue(lines[0].startswith("snapshot: 64x48 PNG of 3 objects in "), lines[0])
        self.assertIn("within 0.01", lines[0])
        self.assertNotIn(" 0 colliding pairs", lines[0])

    def test_camera(self):
        self.local("camera.png", "--width", "32", "--height", "32",
                   "--camera", "2.5,-10,0.5,2.5,0,0.5", "--fov", "30")
        self.assertEqual(png_size(self.out("camera.png")), (32, 32))

    @unittest.skipIf(PROXIMAD is None, "no proximad given")
    def test_server_writes_the_same_bytes(self):
        self.local("a.png", "--width", "80", "--height", "60")
        daemon = Daemon(PROXIMAD, "--log-level", "warn")
        try:
            r = run("snapshot", "--split-components", "--server", daemon.address, "--width", "80",
                    "--height", "60", "--out", self.out("b.png"), self.scene)
            self.assertEqual(r.returncode, 0, r.stderr)
            with open(self.out("a.png"), "rb") as a, open(self.out("b.png"), "rb") as b:
                self.assertEqual(a.read(), b.read(), "--server and local PNGs differ")
        finally:
            self.assertEqual(daemon.stop(), 0)
            daemon.close()

    @unittest.skipIf(PROXIMAD is None, "no proximad given")
    def test_model_region(self):
        # A model of three boxes: 1 pokes up through box 0's top face (a colliding pair), 2 lies
        # 9 away from both.
        meshes = os.path.join(self.tmp, "meshes")
        os.makedirs(meshes, exist_ok=True)
        for i, (lo, hi) in enumerate([((0, 0, 0), (1, 1, 1)), ((0.25, 0.25, 0.5), (0.75, 0.75, 1.5)),
                                      ((10, 0, 0), (11, 1, 1))]):
            write_off(os.path.join(meshes, f"box-{i}.off"), [box_mesh(lo, hi)])
        models = os.path.join(self.tmp, "models")
        p = run_program(PROXIMA, "import", "--store", os.path.join(models, "boxes"), "--quiet",
                        meshes, timeout=100)
        self.assertEqual(p.returncode, 0, p.stderr)
        daemon = Daemon(PROXIMAD, "--models", models, "--gpu", "off", "--log-level", "warn")
        try:
            def shot(name, *args):
                return run("snapshot", "--server", daemon.address, "--model", "boxes",
                           "--width", "41", "--height", "41", "--no-segments",
                           "--out", self.out(name), *args)

            # Looking down at box 0's top face beside box 1 ((0.9, 0.9, 1) on the axis): the
            # middle pixel is box 0's top face, whose triangles box 1 crosses: red.
            near = shot("near.png", "--center", "0.5,0.5,0.5", "--radius", "2",
                        "--camera", "0.9,0.9,10,0.9,0.9,0,0,1,0")
            if near.returncode == 1 and "UNAVAILABLE" in near.stderr and not os.environ.get("CI"):
                self.skipTest(f"no EGL context here: {near.stderr.strip()}")
            self.assertEqual(near.returncode, 0, near.stderr)
            self.assertIn("PNG of model boxes (2 objects, 2 pieces, 24 triangles)", near.stderr)
            self.assertNotIn(" 0 colliding pairs", near.stderr)
            width, height, rows = png_pixels(self.out("near.png"))
            self.assertEqual((width, height), (41, 41))
            self.assertTrue(shade_of(rows[20][20], RED), rows[20][20])
            self.assertEqual(rows[0][0], WHITE)
            # Box 2 is outside the radius: not drawn; the whole model (radius 0) draws it grey.
            far = ["--camera", "10.5,-10,0.5,10.5,0,0.5"]
            r = shot("far-out.png", "--center", "0.5,0.5,0.5", "--radius", "2", *far)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertEqual(png_pixels(self.out("far-out.png"))[2][20][20], WHITE)
            r = shot("far-in.png", *far)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn("(3 objects, 3 pieces, 36 triangles)", r.stderr)
            pixel = png_pixels(self.out("far-in.png"))[2][20][20]
            self.assertTrue(shade_of(pixel, GREY), pixel)
            # max_triangles keeps the nearest pieces.
            r = shot("cut.png", "--center", "10.5,0.5,0.5", "--max-triangles", "12")
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn("(1 objects, 1 pieces, 12 triangles, cut at --max-triangles)", r.stderr)
            # Errors: an unknown model, a room that does not exist, a bad center, no pieces.
            r = run("snapshot", "--server", daemon.address, "--model", "nope", "--out",
                    self.out("x.png"))
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("NOT_FOUND", r.stderr)
            r = shot("x.png", "--room", "nobody")
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("NOT_FOUND: room nobody", r.stderr)
            r = shot("x.png", "--center", "nan,0,0", "--radius", "1")
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("INVALID_ARGUMENT", r.stderr)
            self.assertIn("center", r.stderr)
            r = shot("x.png", "--center", "100,100,100", "--radius", "1")
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("FAILED_PRECONDITION", r.stderr)
            # Usage errors: a negative radius, --model without --server, files and --model.
            r = shot("x.png", "--radius", "-1")
            self.assertEqual(r.returncode, 2, r.stderr)
            r = run("snapshot", "--model", "boxes", "--out", self.out("x.png"))
            self.assertEqual(r.returncode, 2, r.stderr)
            r = run("snapshot", "--server", daemon.address, "--model", "boxes", "--out",
                    self.out("x.png"), self.scene)
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("not both", r.stderr)
        finally:
            self.assertEqual(daemon.stop(), 0)
            daemon.close()

    def test_bad_input(self):
        for args in (["--width", "0"], ["--width", "5000"], ["--height", "-3"], ["--fov", "200"],
                     ["--tolerance", "nan"]):
            r = run("snapshot", *args, "--out", self.out("x.png"), self.scene)
            self.assertEqual(r.returncode, 2, f"{args}: {r.stderr}")
            self.assertIn("Run 'proxima snapshot --help'", r.stderr)
        r = run("snapshot", self.scene)  # no --out
        self.assertEqual(r.returncode, 2, r.stderr)
        r = run("snapshot", "--camera", "1,2,3", "--out", self.out("x.png"), self.scene)
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertIn("INVALID_ARGUMENT: --camera", r.stderr)
        r = run("snapshot", "--camera", "0,0,0,0,0,0", "--out", self.out("x.png"), self.scene)
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertIn("same point", r.stderr)
        r = run("snapshot", "--out", self.out("x.png"), os.path.join(self.tmp, "missing.off"))
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertIn("missing.off", r.stderr)
        r = run("snapshot", "--out", os.path.join(self.tmp, "no", "dir", "x.png"), self.scene)
        if "UNAVAILABLE: snapshot" not in r.stderr:
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("cannot write", r.stderr)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1])
