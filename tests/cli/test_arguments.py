#!/usr/bin/env python3
"""The argument layer of both programs as a user meets it: every numeric parameter refuses nan,
inf and out-of-range values with one line in the project's words and exit status 2 (a usage
error) before anything runs; sizes take K/M/G/T suffixes (powers of 1024, bytes and
triangle counts) in both programs; --version works; a good value still runs (exit 0).

Usage: test_arguments.py PROXIMA PROXIMAD"""
import os
import sys
import tempfile
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
PROXIMAD = sys.argv[2] if len(sys.argv) > 2 else "proximad"

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon, box_mesh, run_program, write_off  # noqa: E402


class Arguments(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-args-")
        cls.a = os.path.join(cls.tmp, "a.off")
        cls.b = os.path.join(cls.tmp, "b.off")
        write_off(cls.a, [box_mesh((0, 0, 0), (1, 1, 1))])
        write_off(cls.b, [box_mesh((1.5, 0, 0), (2.5, 1, 1))])

    def usage_error(self, program, args, option, words):
        p = run_program(program, *args)
        self.assertEqual(p.returncode, 2, f"{args}: {p.stderr}")
        lines = p.stderr.strip().splitlines()
        self.assertEqual(len(lines), 2, p.stderr)
        name = os.path.basename(program)
        self.assertTrue(lines[0].startswith(f"{name}: error: {option}"), lines[0])
        self.assertIn(words, lines[0])
        self.assertLess(len(lines[0]), 200, "one short line, not CLI11's 309-digit ranges")
        self.assertRegex(lines[1], rf"^Run '{name}( [a-z-]+)* --help' for the options\.$")
        self.assertEqual(p.stdout, "", "nothing runs after a usage error")
        return lines

    def test_non_finite_and_out_of_range_numbers_are_usage_errors(self):
        cases = [
            (["distance", "--tolerance", "nan", self.a, self.b], "--tolerance", "finite"),
            (["distance", "--tolerance", "inf", self.a, self.b], "--tolerance", "finite"),
            (["distance", "--tolerance", "-1", self.a, self.b], "--tolerance", ">= 0"),
            (["distance", "--voronoi-cell", "nan", self.a, self.b], "--voronoi-cell", "finite"),
            (["distance", "--voronoi-cell", "0", self.a, self.b], "--voronoi-cell", "> 0"),
            (["distance", "--tolerance", "abc", self.a, self.b], "--tolerance", "a number"),
            (["ccd", "--min-distance", "nan", self.a, self.a], "--min-distance", "finite"),
            (["ccd-queries", "--min-distance", "nan", self.a], "--min-distance", "finite"),
            (["ccd-queries", "--tolerance", "0", self.a], "--tolerance", "> 0"),
            (["ccd-queries", "--max-boxes", "-1", self.a], "--max-boxes", "whole number"),
            (["demo", "--frames", "0"], "--frames", "whole number from 1 to 100000"),
            (["demo", "--frames", "1.5"], "--frames", "whole number"),
            (["verify", "--store", self.tmp, "--tolerance", "nan"], "--tolerance", "finite"),
            (["generate", "plant", "--seed", "-1", "--dir", self.tmp], "--seed", "whole number"),
            (["generate", "plant", "--triangles", "nan", "--dir", self.tmp], "--triangles",
             "suffix"),
            (["import", "--store", self.tmp, "--plant", "10Q"], "--plant", "powers of 1024"),
            (["import", "--store", self.tmp, "--chunk-bytes", "-64K", self.a], "--chunk-bytes",
             "powers of 1024"),
            (["distance", "--server", "127.0.0.1:1", "--inline-mesh-bytes", "lots", self.a],
             "--inline-mesh-bytes", "suffix"),
        ]
        for args, option, words in cases:
            with self.subTest(args=args):
                self.usage_error(PROXIMA, args, option, words)

    def test_the_usage_line_names_the_subcommand(self):
        lines = self.usage_error(PROXIMA, ["generate", "plant", "--seed", "x", "--dir", self.tmp],
                                 "--seed", "whole number")
        self.assertEqual(lines[1], "Run 'proxima generate plant --help' for the options.")

    def test_unknown_options_and_missing_arguments_exit_2(self):
        for args in (["distance", "--no-such-flag", self.a], ["distance"], [], ["no-such-command"]):
            with self.subTest(args=args):
                p = run_program(PROXIMA, *args)
                self.assertEqual(p.returncode, 2, p.stderr)
                self.assertTrue(p.stderr.startswith("proxima: error: "), p.stderr)

    def test_bad_input_exits_1(self):
        missing = os.path.join(self.tmp, "missing.off")
        p = run_program(PROXIMA, "distance", self.a, missing)
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("missing.off", p.stderr)

    def test_good_values_still_run(self):
        p = run_program(PROXIMA, "distance", "--tolerance", "0.75", "--voronoi-cell", "0.5",
                        "--culler", "voronoi-cpu", "--json", self.a, self.b)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn('"within"', p.stdout)

    def test_versions(self):
        for program in (PROXIMA, PROXIMAD):
            p = run_program(program, "--version")
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertRegex(p.stdout.strip(), r"^(proxima )?\d+\.\d+\.\d+$")
        p = run_program(PROXIMA, "version")
        self.assertEqual(p.stdout, run_program(PROXIMA, "--version").stdout)

    def test_help_shows_defaults(self):
        p = run_program(PROXIMA, "import", "--help")
        self.assertEqual(p.returncode, 0)
        self.assertIn("--chunk-bytes", p.stdout)
        self.assertIn("=65536", p.stdout, "the store's real chunk size, not a made-up 1M")
        p = run_program(PROXIMA, "demo", "--help")
        self.assertIn("--frames", p.stdout)
        self.assertRegex(p.stdout, r"--frames \S+[^\n]*=8")
        self.assertRegex(p.stdout, r"--scene TEXT=[a-z-]+")
        p = run_program(PROXIMA, "--help")
        self.assertIn("Exit status: 0 success, 1 bad input or a failed operation, 2 a usage error",
                      p.stdout)

    def test_proximad_sizes_and_usage_errors(self):
        p = run_program(PROXIMAD, "--cache-bytes", "160Q")
        self.assertEqual(p.returncode, 2)
        self.assertTrue(p.stderr.startswith("proximad: error: --cache-bytes"), p.stderr)
        self.assertIn("powers of 1024", p.stderr)
        p = run_program(PROXIMAD, "--help")
        self.assertRegex(p.stdout, r"--cache-bytes [^\n]*SIZE")
        # 160M is accepted: the daemon gets as far as refusing a different, invalid limit.
        p = run_program(PROXIMAD, "--cache-bytes", "160M", "--max-scenes", "0")
        self.assertEqual(p.returncode, 2)
        self.assertNotIn("cache-bytes", p.stderr)
        self.assertIn("limits must be at least 1", p.stderr)


    def test_json_on_stdout_or_out_file_everywhere(self):
        import json
        stdout = run_program(PROXIMA, "distance", "--json", self.a, self.b)
        self.assertEqual(stdout.returncode, 0, stdout.stderr)
        self.assertEqual(len(stdout.stdout.strip().splitlines()), 1, "one line")
        out = os.path.join(self.tmp, "distance.json")
        p = run_program(PROXIMA, "distance", "--out", out, self.a, self.b)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(p.stdout, "")
        self.assertRegex(p.stderr.strip(), rf"^distance: 2 objects, \d+ exact tests; JSON in {out}$")
        with open(out) as f:
            written = json.load(f)
        strip = lambda d: {k: v for k, v in d.items() if k != "stats"}  # noqa: E731
        self.assertEqual(strip(written), strip(json.loads(stdout.stdout)))
        # An unwritable --out is bad input (exit 1), not a crash.
        p = run_program(PROXIMA, "distance", "--out", os.path.join(self.tmp, "no", "dir.json"),
                        self.a, self.b)
        self.assertEqual(p.returncode, 1)
        self.assertIn("cannot write", p.stderr)
        # verify and review: --json is a flag (their default output); the old "--json FILE"
        # is a usage error.
        for command in (["verify", "--store", self.tmp, "--tolerance", "0"],
                        ["review", "--store", self.tmp, "--avatar", self.a, "--path", self.a]):
            with self.subTest(command=command[0]):
                p = run_program(PROXIMA, *command, "--json", out)
                self.assertEqual(p.returncode, 2, p.stderr)
                h = run_program(PROXIMA, command[0], "--help").stdout
                self.assertIn("--out FILE", h)
                self.assertRegex(h, r"--json\s+Print the JSON result")

    def test_a_port_in_use_is_one_clean_line(self):
        daemon = Daemon(PROXIMAD, "--gpu", "off")
        try:
            p = run_program(PROXIMAD, "--listen", daemon.address, "--gpu", "off")
            self.assertEqual(p.returncode, 1)
            lines = p.stderr.strip().splitlines()
            self.assertEqual(len(lines), 1, "gRPC's internal error tree is not printed: " + p.stderr)
            self.assertIn("cannot listen on " + daemon.address, lines[0])
            self.assertIn("port in use", lines[0])
            # Still there for whoever asks for debug lines.
            p = run_program(PROXIMAD, "--listen", daemon.address, "--gpu", "off", "--log-level",
                            "debug")
            self.assertIn("Address already in use", p.stderr)
        finally:
            daemon.stop()

if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
