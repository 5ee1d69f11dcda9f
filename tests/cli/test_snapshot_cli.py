#!/usr/bin/env python3
"""Tests of `proxima snapshot` as a user runs it: a PNG of the asked size and one summary line,
`--server` writes the same bytes as local mode (same renderer: llvmpipe in CI), and bad input is
a usage error (exit 2) or a message with exit 1, never a crash. The pixels themselves are checked
by tests/engine/render/test_snapshot.cpp.
Usage: test_snapshot_cli.py PROXIMA [PROXIMAD]."""
import os
import struct
import sys
import tempfile
import unittest

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
