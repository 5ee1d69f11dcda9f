#!/usr/bin/env python3
"""`proxima verify --shard I/N` and `--merge` (issue #16, docs/massive.md "Shards"): on a
generated plant store, three shard processes run at once (as three machines would), and their
merge equals the single run byte for byte (both with --reproducible, which leaves out the fields
that vary from run to run); without --reproducible the merge has the single run's keys and its
counts. The error cases: a missing shard, a shard given twice, shards of different tolerances,
generations or N, a file that is not a shard output, a bad --shard.
Usage: test_verify_shards.py PROXIMA."""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import run_program as run  # noqa: E402

TOLERANCE = "0.01"
CACHE = "512K"


def read(path):
    with open(path, "rb") as f:
        return f.read()


class VerifyShards(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-verify-shards-")
        cls.store = os.path.join(cls.tmp, "plant")
        p = run(PROXIMA, "import", "--store", cls.store, "--plant", "60K", "--seed", "3",
                "--max-piece-bytes", "32K", "--quiet")
        assert p.returncode == 0, p.stderr
        # The single run (it also persists the schedule: the shards read the same one, or plan
        # the same one, deterministically).
        cls.single = os.path.join(cls.tmp, "single.json")
        p = run(PROXIMA, "verify", "--store", cls.store, "--tolerance", TOLERANCE,
                "--cache-bytes", CACHE, "--reproducible", "--quiet", "--out", cls.single)
        assert p.returncode == 0, p.stderr
        cls.shards = cls.run_shards(3, TOLERANCE)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def run_shards(cls, n, tolerance, extra=(), tag=""):
        """N shard processes at once; their output files."""
        outs = [os.path.join(cls.tmp, f"shard{tag}-t{tolerance}-{i}of{n}.json") for i in range(n)]
        procs = [subprocess.Popen([PROXIMA, "verify", "--store", cls.store, "--tolerance",
                                   tolerance, "--cache-bytes", CACHE, "--shard", f"{i}/{n}",
                                   "--quiet", "--out", outs[i], *extra],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for i in range(n)]
        for p in procs:
            _, err = p.communicate(timeout=120)
            assert p.returncode == 0, err
        return outs

    def merge(self, *files, extra=("--reproducible",)):
        out = os.path.join(self.tmp, "merged.json")
        if os.path.exists(out):
            os.remove(out)
        p = run(PROXIMA, "verify", "--merge", *files, *extra, "--quiet", "--out", out)
        return p, out

    def test_merge_equals_the_single_run_byte_for_byte(self):
        single = json.loads(read(self.single))
        self.assertGreater(len(single["pairs"]), 5, "the model must have pairs to find")
        docs = [json.loads(read(f)) for f in self.shards]
        # Every piece pair is in exactly one shard, and more than one shard has work.
        self.assertEqual(sum(d["shard"]["piece_pair_count"] for d in docs),
                         single["stats"]["piece_pair_count"])
        self.assertEqual(sum(d["shard"]["subgraph_count"] for d in docs),
                         single["stats"]["subgraph_count"])
        self.assertGreaterEqual(sum(1 for d in docs if d["shard"]["piece_pair_count"] > 0), 2)
        # Some object pairs have piece pairs in several shards: the merge must pick the best.
        seen = {}
        for d in docs:
            for p in d["pairs"]:
                seen[(p["object"], p["other"])] = seen.get((p["object"], p["other"]), 0) + 1
        self.assertTrue(any(n > 1 for n in seen.values()), seen)
        for i, d in enumerate(docs):
            self.assertEqual((d["shard"]["index"], d["shard"]["count"]), (i, 3))
            self.assertEqual(d["generation"], single["generation"])
        p, merged = self.merge(*reversed(self.shards))  # any order
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(read(merged), read(self.single))

    def test_merge_without_reproducible_has_the_single_runs_keys(self):
        p, merged = self.merge(*self.shards, extra=())
        self.assertEqual(p.returncode, 0, p.stderr)
        doc = json.loads(read(merged))
        self.assertIn("seconds", doc["stats"])
        self.assertIn("cache", doc["stats"])
        single = json.loads(read(self.single))
        self.assertEqual(doc["pairs"], single["pairs"])
        for key in single["stats"]:
            self.assertEqual(doc["stats"][key], single["stats"][key], key)

    def test_the_sharding_is_deterministic(self):
        again = self.run_shards(3, TOLERANCE, tag="again", extra=("--reproducible",))
        first = self.run_shards(3, TOLERANCE, tag="first", extra=("--reproducible",))
        for a, b in zip(again, first):
            self.assertEqual(read(a), read(b))

    def test_missing_shard(self):
        p, _ = self.merge(self.shards[0], self.shards[2])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("shard(s) 1 of 3 missing", p.stderr)

    def test_duplicate_shard(self):
        p, _ = self.merge(self.shards[0], self.shards[1], self.shards[1], self.shards[2])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("shard 1/3 given twice", p.stderr)

    def test_shards_of_different_runs(self):
        other_n = self.run_shards(2, TOLERANCE, tag="n2")
        p, _ = self.merge(self.shards[0], self.shards[1], other_n[1])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("different runs", p.stderr)
        other_t = self.run_shards(3, "0.02", tag="t")
        p, _ = self.merge(self.shards[0], other_t[1], self.shards[2])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("tolerance", p.stderr)
        # Another generation: the same shard output claiming another store generation.
        doc = json.loads(read(self.shards[1]))
        doc["generation"] = "0" * len(doc["generation"])
        forged = os.path.join(self.tmp, "forged.json")
        with open(forged, "w") as f:
            json.dump(doc, f)
        p, _ = self.merge(self.shards[0], forged, self.shards[2])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("generation", p.stderr)

    def test_not_a_shard_output(self):
        p, _ = self.merge(self.single, self.shards[1])
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("is not the output of proxima verify --shard", p.stderr)
        p, _ = self.merge(os.path.join(self.tmp, "absent.json"))
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("cannot read", p.stderr)

    def test_bad_shard_argument(self):
        for bad in ("3/3", "1", "a/3", "-1/3", "1/0", "1/3x"):
            p = run(PROXIMA, "verify", "--store", self.store, "--tolerance", TOLERANCE,
                    "--shard", bad, "--quiet")
            self.assertNotEqual(p.returncode, 0, bad)
            self.assertIn("--shard", p.stderr, bad)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=1)
