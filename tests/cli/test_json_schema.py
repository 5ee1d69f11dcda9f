#!/usr/bin/env python3
"""Every JSON document the command line prints, checked against docs/json-output.schema.json (the
vocabulary of docs/api.md, "JSON output"), for every subcommand that prints one, in local and
server mode:

- the document validates against the command's schema (`additionalProperties: false`, so a
  field that is not documented fails);
- it is printed as one line on standard output (`demo --json`: one line per frame);
- `--out FILE` writes the same document to FILE, prints nothing on standard output and one line
  on standard error ending in "; JSON in FILE";
- the vocabulary holds everywhere, whatever the schema says: a key ending in `_count` is a whole
  number, a key naming a list (objects, pairs, collisions, ...) is an array, a `point` is three
  numbers or null, a `box` is {"lo", "hi"}, and the closest-pair keys come in the one order-free
  set of names (no `_a`/`_b`, `object_point`, `closest`).

Needs the jsonschema module (Debian's python3-jsonschema, for /usr/bin/python3).
Usage: test_json_schema.py PROXIMA PROXIMAD SCHEMA [DATA_DIR]
Set PROXIMA_SCHEMA_SAMPLES=DIR to also write every document checked to DIR (to read them).
"""
import json
import os
import shutil
import sys
import tempfile
import unittest

import jsonschema

PROXIMA, PROXIMAD, SCHEMA = sys.argv[1:4]
DATA = sys.argv[4] if len(sys.argv) > 4 else ""

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, box_mesh, write_off  # noqa: E402
from cli_helpers import run_program  # noqa: E402

# Names that always hold a list when they appear as a key.
LIST_KEYS = {"objects", "pairs", "object_pairs", "collisions", "pns", "self",
             "penetrations", "poses", "within", "models", "unavailable", "results", "tois",
             "triangles", "other_triangles"}
# Names of the old shapes that the vocabulary replaced.
RETIRED_KEYS = {"object_a", "object_b", "name_a", "name_b", "triangle_a", "triangle_b", "point_a",
                "point_b", "object_triangle", "avatar_triangle", "object_point", "avatar_point",
                "object_list", "pairs_found", "queries"}

with open(SCHEMA) as f:
    SCHEMA_DOC = json.load(f)


def validator(command):
    schema = dict(SCHEMA_DOC)
    schema["$ref"] = f"#/$defs/{command}"
    return jsonschema.Draft202012Validator(schema)


def walk(doc, path="$"):
    """Yields (path, key, value) for every key of every object in `doc`."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield path, k, v
            yield from walk(v, f"{path}.{k}")
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from walk(v, f"{path}[{i}]")


class JsonOutput(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-json-schema-")
        cls.samples = os.environ.get("PROXIMA_SCHEMA_SAMPLES", "")
        cls.checked = set()
        t = cls.tmp
        cls.a, cls.b, cls.c = (os.path.join(t, n) for n in ("a.off", "b.off", "c.off"))
        write_off(cls.a, [box_mesh((0, 0, 0), (1, 1, 1))])
        write_off(cls.b, [box_mesh((1.5, 0, 0), (2.5, 1, 1))])
        write_off(cls.c, [box_mesh((0.5, 0.5, 0.5), (1.5, 1.5, 1.5))])
        # Two frames for ccd: b moves through a.
        cls.t0 = os.path.join(t, "t0.off")
        cls.t1 = os.path.join(t, "t1.off")
        write_off(cls.t0, [box_mesh((0, 0, 0), (1, 1, 1)), box_mesh((1.5, 0.2, 0.2), (2, 0.8, 0.8))])
        write_off(cls.t1, [box_mesh((0, 0, 0), (1, 1, 1)), box_mesh((0.5, 0.2, 0.2), (1, 0.8, 0.8))])
        # A vertex dropping through a triangle (hit), in the public CCD query format with truth.
        cls.csv = os.path.join(t, "vf.csv")
        pts = [(0.25, 0.25, 1), (0, 0, 0), (1, 0, 0), (0, 1, 0),
               (0.25, 0.25, -1), (0, 0, 0), (1, 0, 0), (0, 1, 0)]
        with open(cls.csv, "w") as out:
            for p in pts:
                out.write(",".join(f"{int(c * 4)},4" for c in p) + ",1\n")
        # A generated plant, imported into a store the daemon serves as model "plant".
        cls.plant = os.path.join(t, "plant")
        cls.models = os.path.join(t, "models")
        cls.store = os.path.join(cls.models, "plant")
        cls.avatar = os.path.join(t, "avatar.off")
        write_off(cls.avatar, [box_mesh((-0.2, -0.2, -0.2), (0.2, 0.2, 0.2))])
        cls.path = os.path.join(t, "path.txt")
        with open(cls.path, "w") as out:
            for k in range(4):
                out.write(f"{1.0 + k}, 1.0, 1.0\n")
        p = run_program(PROXIMA, "generate", "plant", "--triangles", "8K", "--dir", cls.plant,
                        "--quiet")
        assert p.returncode == 0, p.stderr
        p = run_program(PROXIMA, "import", "--store", cls.store, "--quiet",
                        os.path.join(cls.plant, "scene.json"))
        assert p.returncode == 0, p.stderr
        cls.daemon = Daemon(PROXIMAD, "--models", cls.models)

    @classmethod
    def tearDownClass(cls):
        cls.daemon.stop()
        cls.daemon.close()
        shutil.rmtree(cls.tmp, ignore_errors=True)
        # Every command of the schema was run by some test.
        missing = set(SCHEMA_DOC["x-commands"]) - cls.checked
        assert not missing, f"schema commands never checked: {sorted(missing)}"

    # --- the checks ------------------------------------------------------------------------------

    def check_vocabulary(self, doc, where):
        for path, k, v in walk(doc):
            at = f"{where}: {path}.{k}"
            self.assertNotIn(k, RETIRED_KEYS, f"{at}: a retired name")
            if k.endswith("_count"):
                self.assertTrue(isinstance(v, int) and not isinstance(v, bool) and v >= 0,
                                f"{at} = {v!r}: a count is a whole number")
            if k in LIST_KEYS:
                self.assertIsInstance(v, list, f"{at}: a list key holds an array")
            if k in ("point", "other_point") and v is not None:
                self.assertTrue(isinstance(v, list) and len(v) == 3, f"{at}: [x, y, z]")
            if k == "box":
                self.assertEqual(set(v), {"lo", "hi"}, f"{at}: a box is {{lo, hi}}")

    def check(self, command, *args, lines=False, out_args=None, same_values=True):
        """Runs `proxima ARGS` (JSON on stdout), validates it as `command`, then the same (or
        `out_args`) with --out FILE. Returns the document (the list of documents with `lines`).
        `same_values=False`: the --out run's document validates too, but its values differ (a
        load run's figures), so only its keys are compared."""
        p = run_program(PROXIMA, *args)
        self.assertEqual(p.returncode, 0, f"{args}: {p.stderr}")
        out = p.stdout.splitlines()
        self.assertTrue(out, f"{args}: nothing on standard output")
        if not lines:
            self.assertEqual(len(out), 1, f"{args}: one line of JSON, got {len(out)}")
        docs = [json.loads(x) for x in out]
        v = validator(command)
        for doc in docs:
            errors = sorted(v.iter_errors(doc), key=lambda e: list(e.absolute_path))
            self.assertFalse(errors, f"{args}: " + "; ".join(
                f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in errors[:5]))
            self.check_vocabulary(doc, " ".join(args[:2]))
        self.checked.add(command)
        if self.samples:
            os.makedirs(self.samples, exist_ok=True)
            name = "-".join(a.strip("-") for a in args[:3] if "/" not in a)
            with open(os.path.join(self.samples, f"{command}--{name}.json"), "w") as f:
                json.dump(docs if lines else docs[0], f, indent=1)
        self.check_out_file(out_args or args, docs, lines, same_values, v)
        return docs if lines else docs[0]

    def check_out_file(self, args, docs, lines, same_values=True, v=None):
        """The same command with --out FILE instead of --json: the same document(s) in the file,
        one line each."""
        target = os.path.join(self.tmp, "out.json")
        if os.path.exists(target):
            os.remove(target)
        argv = [a for a in args if a != "--json"]
        n = 2 if argv[0] == "generate" else 1  # after the (sub)subcommand
        p = run_program(PROXIMA, *argv[:n], "--out", target, *argv[n:])
        self.assertEqual(p.returncode, 0, f"{argv} --out: {p.stderr}")
        self.assertEqual(p.stdout, "", f"{argv} --out: nothing on standard output")
        err = [x for x in p.stderr.splitlines() if x.strip()]
        self.assertEqual(len(err), 1, f"{argv} --out: one summary line, got {err}")
        self.assertTrue(err[0].endswith(f"; JSON in {target}"), err[0])
        with open(target) as f:
            text = f.read()
        self.assertEqual(text.count("\n"), len(docs), "one line per document in the file")
        written = [json.loads(x) for x in text.splitlines()]
        if not same_values:
            for doc in written:
                errors = list(v.iter_errors(doc))
                self.assertFalse(errors, f"{argv} --out: {errors[:1]}")
            self.assertEqual([sorted(d) for d in written], [sorted(d) for d in docs])
            return
        # Timings differ from run to run; the answer and the shape do not.
        self.assertEqual(strip_times(written), strip_times(docs), f"{argv}: --out vs --json")

    def test_the_schema_rejects_the_old_shapes(self):
        """The schema is strict: the shapes the vocabulary replaced do not validate."""
        def valid(command, doc):
            return validator(command).is_valid(doc)
        pair = {"object": 0, "name": "a", "triangle": 1, "point": [0, 0, 0], "other": 1,
                "other_name": "b", "other_triangle": 2, "other_point": [0, 0, 1], "distance": 1.0}
        verify = {"tolerance": 1.0, "method": "static", "pairs": [pair],
                  "stats": {"pair_count": 1, "object_count": 2, "seconds": 0.1}}
        self.assertTrue(valid("verify", verify))
        old = dict(verify, pairs=[{"object_a": 0, "object_b": 1, "name_a": "a", "name_b": "b",
                                   "distance": 1.0, "triangle_a": 1, "triangle_b": 2,
                                   "point_a": [0, 0, 0], "point_b": [0, 0, 1]}])
        self.assertFalse(valid("verify", old))
        self.assertFalse(valid("verify", dict(verify, stats={"pairs_found": 1, "objects": 2,
                                                             "seconds": 0.1})))
        box = {"lo": [0, 0, 0], "hi": [1, 1, 1]}
        info = {"store": "s", "generation": "gen-000001", "object_count": 1, "piece_count": 1,
                "split_object_count": 0, "triangle_count": 12, "vertex_count": 8,
                "chunk_count": 1, "bytes": 10, "largest_piece_weight": 5}
        obj = {"name": "a", "box": box, "vertex_count": 8, "triangle_count": 12,
               "first_piece": 0, "piece_count": 1}
        self.assertTrue(valid("store-info", dict(info, objects=[obj])))
        self.assertFalse(valid("store-info", dict(info, object_list=[dict(obj, box=[0, 0, 0, 1, 1, 1])])))
        self.assertFalse(valid("store-info", dict(info, objects=[dict(obj, box=[0, 0, 0, 1, 1, 1])])))
        self.assertFalse(valid("store-info", dict(info, objects=3)))

    # --- local commands --------------------------------------------------------------------------

    def test_distance(self):
        doc = self.check("distance", "distance", "--json", "--self", "--collisions",
                         "--tolerance", "0.6", "--pns", self.a, self.b)
        self.assertEqual(doc["objects"][0]["separation"]["distance"], 0.5)
        self.assertEqual(len(doc["self"]), 24)
        self.assertGreater(len(doc["within"]), 0)
        doc = self.check("distance", "distance", "--json", "--penetration", self.a, self.c)
        self.assertGreater(len(doc["penetrations"]), 0)
        doc = self.check("distance", "distance", "--json", self.a)
        self.assertIsNone(doc["objects"][0]["separation"]["distance"])
        doc = self.check("distance", "distance", "--json", "--server", self.daemon.address,
                         "--collisions", self.a, self.c)
        self.assertGreater(len(doc["collisions"]), 0)

    def test_demo(self):
        docs = self.check("demo", "demo", "--json", "--frames", "2", "--scene", "bowl", lines=True)
        self.assertEqual([d["frame"] for d in docs], [0, 1])
        docs = self.check("demo", "demo", "--json", "--frames", "2", "--scene", "bowl", "--server",
                          self.daemon.address, lines=True)
        self.assertTrue(all(d["round_trip_ms"] > 0 for d in docs))

    def test_play(self):
        # A two-frame sequence: the ccd frames' boxes, played with every query.
        seq = os.path.join(self.tmp, "sequence")
        os.makedirs(seq, exist_ok=True)
        shutil.copy(self.t0, os.path.join(seq, "frame_0.off"))
        shutil.copy(self.t1, os.path.join(seq, "frame_1.off"))
        for extra in ((), ("--server", self.daemon.address)):
            docs = self.check("play", "play", "--json", seq, "--split-components", "--query",
                              "separation,self,collisions,ccd", "--tolerance", "0.1", *extra,
                              lines=True)
            self.assertEqual([d["frame"] for d in docs], [0, 1])
            self.assertIsNone(docs[0]["ccd"])
            self.assertIsNotNone(docs[1]["ccd"]["toi"])
        docs = self.check("play", "play", "--json", seq, lines=True)
        self.assertNotIn("ccd", docs[0])
        doc = self.check("generate", "generate", "sequence", "--json", "--frames", "3", "--dir",
                         os.path.join(self.tmp, "breaking"), "--quiet")
        self.assertEqual(doc["frame_count"], 3)

    def test_ccd(self):
        doc = self.check("ccd", "ccd", "--json", self.t0, self.t1)
        self.assertIsNotNone(doc["earliest"])
        doc = self.check("ccd", "ccd", "--json", "--server", self.daemon.address, self.t0, self.t1)
        self.assertIsNotNone(doc["earliest"])

    def test_ccd_queries(self):
        doc = self.check("ccd-queries", "ccd-queries", "--json", "--kind", "vf", self.csv)
        self.assertEqual(doc["query_count"], 1)
        self.assertEqual(doc["false_negative_count"], 0)

    def test_generate(self):
        doc = self.check("generate", "generate", "plant", "--json", "--triangles", "4K", "--dir",
                         os.path.join(self.tmp, "plant-2"), "--quiet")
        self.assertGreater(doc["triangle_count"], 3000)
        furniture = os.path.join(DATA, "meshes", "furniture-cc0")
        if DATA and os.path.isdir(furniture):
            self.check("generate", "generate", "building", "--json", "--furniture", furniture,
                       "--triangles", "60K", "--dir", os.path.join(self.tmp, "building"),
                       "--quiet")

    def test_import_and_store_info(self):
        store = os.path.join(self.tmp, "store-2")
        # (--out into another store: a second import into the same one would be a re-import.)
        doc = self.check("import", "import", "--json", "--store", store, "--quiet", self.a, self.b,
                         out_args=("import", "--json", "--store", store + "-out", "--quiet",
                                   self.a, self.b))
        self.assertEqual(doc["object_count"], 2)
        doc = self.check("store-info", "store-info", "--json", "--store", store)
        self.assertNotIn("objects", doc)
        doc = self.check("store-info", "store-info", "--json", "--store", store, "--objects",
                         "--verify", "--quiet")
        self.assertEqual([os.path.basename(o["name"]) for o in doc["objects"]], ["a.off", "b.off"])
        self.assertEqual(doc["objects"][0]["box"], {"lo": [0, 0, 0], "hi": [1, 1, 1]})

    def test_verify(self):
        local = self.check("verify", "verify", "--json", "--store", self.store, "--tolerance",
                           "0.05", "--quiet")
        self.assertGreater(len(local["pairs"]), 0)
        brute = self.check("verify", "verify", "--json", "--store", self.store, "--tolerance",
                           "0.05", "--brute-force", "--quiet")
        self.assertEqual(local["pairs"], brute["pairs"])
        remote = self.check("verify", "verify", "--json", "--server", self.daemon.address,
                            "--model", "plant", "--tolerance", "0.05", "--quiet")
        self.assertEqual(local["pairs"], remote["pairs"])

    def test_region(self):
        whole = self.check("region", "region", "--json", "--server", self.daemon.address,
                           "--model", "plant", "--quiet")
        self.assertEqual(whole["piece_count"], len(whole["pieces"]))
        near = self.check("region", "region", "--json", "--server", self.daemon.address,
                          "--model", "plant", "--center", "1,2,0.5", "--radius", "3",
                          "--max-triangles", "5000", "--quiet")
        self.assertLessEqual(near["triangle_count"], 5000)

    def test_review(self):
        local = self.check("review", "review", "--json", "--store", self.store, "--avatar",
                           self.avatar, "--path", self.path, "--tolerance", "0.5", "--quiet")
        self.assertEqual(len(local["poses"]), 4)
        remote = self.check("review", "review", "--json", "--server", self.daemon.address,
                            "--model", "plant", "--avatar", self.avatar, "--path", self.path,
                            "--tolerance", "0.5", "--quiet")
        self.assertEqual([p["collisions"] for p in local["poses"]],
                         [p["collisions"] for p in remote["poses"]])

    # --- daemon commands -------------------------------------------------------------------------

    def test_load(self):
        doc = self.check("load", "load", "--json", "--server", self.daemon.address, "--duration",
                         "1500ms", "--warmup", "500ms", "--clients", "sim=1,review=1", "--scene",
                         "bowl", "--queries", "separation,tolerance", "--quiet", same_values=False)
        self.assertGreater(doc["kinds"]["sim_frame"]["count"], 0)
        self.assertGreater(doc["kinds"]["review_pose"]["count"], 0)
        self.assertEqual(doc["metrics"]["endpoints"], [])

    def test_info(self):
        doc = self.check("info", "info", "--json", "--server", self.daemon.address)
        self.assertEqual(doc["api"], "proxima.v1")

    def test_models(self):
        doc = self.check("models", "models", "--json", "--server", self.daemon.address)
        self.assertEqual([m["name"] for m in doc["models"]], ["plant"])


TIME_KEYS = {"seconds", "round_trip_ms", "latency_ms", "late_ms", "triangles_per_second",
             "bytes_per_second",
             "verify_seconds", "plan_seconds", "worst_seconds", "cache", "stats", "replaced_generation",
             "generation", "store", "member"}


def strip_times(doc):
    if isinstance(doc, dict):
        return {k: strip_times(v) for k, v in doc.items()
                if k not in TIME_KEYS and not k.endswith("_seconds")}
    if isinstance(doc, list):
        return [strip_times(v) for v in doc]
    return doc


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], "-v"])
