#!/usr/bin/env python3
"""docs/plots/plot_all.py (issue #17 item 4): redraws every plot of docs/plots from the committed
JSON files into a temporary folder: one PNG per JSON file, each a real PNG of the size its layout
gives (dvd_resolution: 1500 wide, 330 px per scene/query row plus the title; the load report:
1100 x 900 with its daemon panel), the same size as the PNG committed beside it. A JSON file of no
known shape is an error naming the file. With PROXIMA_DVD_BENCH: a --quick --no-gpu run writes
--csv and --json with the same rows, and the script plots that JSON. gnuplot is installed by
deploy/setup.sh, so its absence fails the test.
Usage: test_plots.py PLOTS_DIR [PROXIMA_DVD_BENCH]."""
import csv
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest

PLOTS = os.path.abspath(sys.argv[1])
DVD_BENCH = sys.argv[2] if len(sys.argv) > 2 else ""
SCRIPT = os.path.join(PLOTS, "plot_all.py")


def png_size(path):
    """(width, height) from a PNG's IHDR chunk; fails on anything that is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", f"{path} is not a PNG"
    return struct.unpack(">II", head[16:24])


def expected_size(doc):
    if doc.get("tool") == "proxima_dvd_bench":
        panels = {(r["scene"], r["query"]) for r in doc["rows"]}
        return 1500, 330 * len(panels) + 60
    metrics = any(len(e.get("samples", [])) > 1 for e in doc["metrics"]["endpoints"])
    return 1100, 900 if metrics else 640


def plot(*args):
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True,
                          timeout=60)


class Plots(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="proxima-plots-")

    def tearDown(self):
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_gnuplot_installed(self):
        self.assertIsNotNone(shutil.which("gnuplot"), "gnuplot (Debian gnuplot-nox) is missing")

    def test_every_committed_plot(self):
        names = sorted(n[:-5] for n in os.listdir(PLOTS) if n.endswith(".json"))
        self.assertIn("dvd_resolution", names)
        self.assertIn("load-example", names)
        p = plot("--out", self.tmp)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(sorted(os.listdir(self.tmp)), sorted(n + ".png" for n in names))
        for name in names:
            with open(os.path.join(PLOTS, name + ".json")) as f:
                doc = json.load(f)
            size = png_size(os.path.join(self.tmp, name + ".png"))
            self.assertEqual(size, expected_size(doc), name)
            self.assertGreater(os.path.getsize(os.path.join(self.tmp, name + ".png")), 20000, name)
            committed = os.path.join(PLOTS, name + ".png")
            self.assertTrue(os.path.exists(committed), f"{committed} is not committed")
            self.assertEqual(png_size(committed), size, f"{committed}: redraw and commit it")
        self.assertEqual(png_size(os.path.join(PLOTS, "snapshot-demo.png")), (800, 600))

    def test_unknown_json_is_an_error(self):
        data = os.path.join(self.tmp, "data")
        os.mkdir(data)
        with open(os.path.join(data, "other.json"), "w") as f:
            json.dump({"something": "else"}, f)
        p = plot("--data", data, "--out", self.tmp)
        self.assertEqual(p.returncode, 1)
        self.assertIn("other.json", p.stderr)
        self.assertIn("not a JSON document this script knows", p.stderr)

    @unittest.skipUnless(DVD_BENCH, "no proxima_dvd_bench (benchmarks not built)")
    def test_dvd_bench_json_equals_csv(self):
        js, cs = os.path.join(self.tmp, "quick.json"), os.path.join(self.tmp, "quick.csv")
        p = subprocess.run([DVD_BENCH, "--quick", "--no-gpu", "--json", js, "--csv", cs],
                           capture_output=True, text=True, timeout=120)
        self.assertEqual(p.returncode, 0, p.stderr)
        with open(js) as f:
            doc = json.load(f)
        with open(cs) as f:
            rows = list(csv.DictReader(f))
        self.assertEqual(doc["tool"], "proxima_dvd_bench")
        self.assertEqual(doc["device"], "cpu")
        self.assertEqual(doc["frames"], 2)
        self.assertEqual(doc["cells"], ["auto"])
        self.assertTrue(doc["cpu"])
        self.assertEqual(len(doc["rows"]), len(rows))
        self.assertGreater(len(rows), 0)
        for j, c in zip(doc["rows"], rows):
            for k in ("scene", "query", "culler"):
                self.assertEqual(j[k], c[k])
            self.assertEqual(j["triangles"], int(c["triangles"]))
            self.assertEqual(j["mismatches"], 0)
            if j["culler"] == "bvh":
                self.assertIsNone(j["cell_factor"])
                self.assertIsNone(j["cell"])
            else:
                self.assertEqual(j["cell_factor"], c["cell_factor"])
                self.assertAlmostEqual(j["cell"], float(c["cell"]), delta=1e-5 * j["cell"])
            for k in ("total_ms", "exact_tests", "bvh_exact_tests", "samples"):
                self.assertAlmostEqual(j[k], float(c[k]), delta=1e-5 * max(1.0, j[k]), msg=k)
        out = os.path.join(self.tmp, "out")
        p = plot("--data", self.tmp, "--out", out)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(png_size(os.path.join(out, "quick.png")), expected_size(doc))


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
