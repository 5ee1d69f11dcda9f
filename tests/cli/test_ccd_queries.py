#!/usr/bin/env python3
"""`proxima ccd-queries` as a user runs it: the JSON shape on a file of the public CCD benchmark,
zero false negatives, the kind from the path or --kind, and clear errors (exit 1, a message on
stderr, never a crash) for malformed files. Usage: test_ccd_queries.py PROXIMA [DATA_DIR]."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
DATA = sys.argv[2] if len(sys.argv) > 2 else ""

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import run_program  # noqa: E402


def run(*args):
    return run_program(PROXIMA, "ccd-queries", *args)


def data_file(*parts):
    path = os.path.join(DATA, "ccd-queries", *parts)
    return path if DATA and os.path.isfile(path) else None


# A vertex dropping through a static triangle at t = 1/2 (hit), then the same beside it (miss).
def vf_rows(x, truth):
    pts = [(x, 0.25, 1), (0, 0, 0), (1, 0, 0), (0, 1, 0),
           (x, 0.25, -1), (0, 0, 0), (1, 0, 0), (0, 1, 0)]
    rows = []
    for p in pts:
        cols = []
        for c in p:
            cols += [str(int(c * 4)), "4"]
        rows.append(",".join(cols + ([str(truth)] if truth is not None else [])))
    return "\n".join(rows) + "\n"


class CcdQueries(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-ccd-queries-")

    def write(self, name, text):
        path = os.path.join(self.tmp, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def check_shape(self, doc, n):
        for key in ("results", "tois", "false_negative_count", "false_positive_count", "seconds"):
            self.assertIn(key, doc)
        self.assertEqual(len(doc["results"]), n)
        self.assertEqual(len(doc["tois"]), n)
        self.assertEqual(doc["query_count"], n)
        for hit, toi in zip(doc["results"], doc["tois"]):
            self.assertIsInstance(hit, bool)
            if hit:
                self.assertTrue(0.0 <= toi <= 1.0, toi)
            else:
                self.assertIsNone(toi)
        self.assertGreaterEqual(doc["seconds"], 0.0)

    def test_benchmark_file(self):
        path = data_file("unit-tests", "edge-edge", "data_0_0.csv")
        if path is None:
            self.skipTest("CCD benchmark data not found (DATA_DIR/ccd-queries)")
        p = run("--json", path)
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        with open(path) as f:
            rows = [line.strip().split(",") for line in f if line.strip()]
        truth = [rows[i][6] == "1" for i in range(0, len(rows), 8)]
        self.check_shape(doc, len(truth))
        self.assertEqual(doc["kind"], "ee")
        self.assertEqual(doc["false_negative_count"], 0)
        self.assertEqual(doc["false_negative_count"],
                         sum(t and not r for t, r in zip(truth, doc["results"])))
        self.assertEqual(doc["false_positive_count"],
                         sum(r and not t for t, r in zip(truth, doc["results"])))
        # The text summary says the same.
        p = run(path)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("0 false negatives", p.stdout)

    def test_known_answers_and_kind(self):
        # No kind in the path: --kind is needed.
        path = self.write("queries.csv", vf_rows(0.25, 1) + vf_rows(1.0, 0))
        p = run("--json", path)
        self.assertEqual(p.returncode, 1)
        self.assertIn("--kind", p.stderr)
        p = run("--json", "--kind", "vf", path)
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        self.check_shape(doc, 2)
        self.assertEqual(doc["results"], [True, False])
        self.assertTrue(0.5 - 1e-6 <= doc["tois"][0] <= 0.5, doc["tois"])
        self.assertEqual(doc["false_negative_count"], 0)
        self.assertEqual(doc["false_positive_count"], 0)
        # The kind from the path; six columns (no truth): counts are null.
        os.makedirs(os.path.join(self.tmp, "vertex-face"), exist_ok=True)
        six = self.write(os.path.join("vertex-face", "six.csv"), vf_rows(0.25, None))
        p = run("--json", six)
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(p.stdout)
        self.assertEqual(doc["results"], [True])
        self.assertIsNone(doc["false_negative_count"])
        # Minimum distance: the miss passes 0.18 from the hypotenuse, within 0.5.
        p = run("--json", "--kind", "vf", "--min-distance", "0.5", path)
        self.assertEqual(json.loads(p.stdout)["results"], [True, True])

    def test_malformed_files(self):
        cases = {
            "columns.csv": ("1,1,1,1,1\n", ":1:"),
            "zero.csv": ("1,1,1,0,1,1,0\n", "zero denominator"),
            "nonint.csv": ("1,1,0.5,1,1,1,0\n", "not an integer"),
            "rows.csv": (vf_rows(0.25, 1) + "1,1,1,1,1,1,1\n", "not a multiple of 8"),
            "huge.csv": ("1" + "0" * 400 + ",1,1,1,1,1,0\n", "not finite"),
        }
        for name, (text, message) in cases.items():
            path = self.write(name, text)
            p = run("--json", "--kind", "ee", path)
            self.assertEqual(p.returncode, 1, (name, p.stdout, p.stderr))
            self.assertIn(message, p.stderr, name)
            self.assertIn(name, p.stderr)
            self.assertEqual(p.stdout, "", name)
        p = run("--kind", "ee", os.path.join(self.tmp, "missing.csv"))
        self.assertEqual(p.returncode, 1)
        self.assertIn("missing.csv", p.stderr)

    def test_usage_errors(self):
        path = self.write("u.csv", vf_rows(0.25, 1))
        for args in (["--kind", "fv", path], ["--tolerance", "-1", path], [],
                     ["--min-distance", "x", path]):
            p = run(*args)
            self.assertNotIn(p.returncode, (0, 1), args)
            self.assertNotEqual(p.stderr, "", args)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0]])
