#!/usr/bin/env python3
"""The flags every --server subcommand shares (issue #7): --token-file, PROXIMA_TOKEN, --tls-ca,
--tls-cert, --tls-key, --tls-server-name. Their error cases are exit 1 with
`proxima: error: CODE: message` naming the file; a token file every user can read is a warning;
each subcommand that talks to a daemon takes them and they need --server where it is optional.
With PROXIMAD given, a plaintext daemon (which checks no tokens) serves `info` with a token, and a
TLS client facing it fails UNAVAILABLE saying TLS is involved.
Usage: test_server_flags.py PROXIMA [PROXIMAD]."""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import unittest

PROXIMA = sys.argv[1] if len(sys.argv) > 1 else "proxima"
PROXIMAD = sys.argv[2] if len(sys.argv) > 2 else None

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from cli_helpers import Daemon as SharedDaemon, run_program as run  # noqa: E402

BOX_OFF = """OFF
8 12 0
0 0 0
1 0 0
0 1 0
1 1 0
0 0 1
1 0 1
0 1 1
1 1 1
3 0 2 1
3 1 2 3
3 4 5 6
3 5 7 6
3 0 1 4
3 1 5 4
3 2 6 3
3 3 6 7
3 0 4 2
3 2 4 6
3 1 3 5
3 3 7 5
"""


class Daemon(SharedDaemon):
    """proximad on a free loopback port, logging warnings only."""

    def __init__(self, *flags):
        super().__init__(PROXIMAD, "--log-level", "warn", *flags)


class ServerFlags(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-flags-")
        cls.box = os.path.join(cls.tmp, "box.off")
        with open(cls.box, "w") as f:
            f.write(BOX_OFF)
        cls.path = os.path.join(cls.tmp, "path.txt")
        with open(cls.path, "w") as f:
            f.write("0 0 0\n")
        cls.token = cls.write("token", "  s3cret-token  \nsecond line ignored\n", 0o600)
        cls.open_token = cls.write("open-token", "s3cret-token\n", 0o644)
        cls.empty_token = cls.write("empty-token", "   \nnot the first line\n", 0o600)
        cls.not_pem = cls.write("not-pem.crt", "hello\n", 0o644)
        # Port 1: nobody listens there, so a command that got past its flags fails UNAVAILABLE.
        cls.nowhere = "127.0.0.1:1"

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def write(cls, name, text, mode):
        path = os.path.join(cls.tmp, name)
        with open(path, "w") as f:
            f.write(text)
        os.chmod(path, mode)
        return path

    def server_commands(self, address):
        """Every subcommand that talks to a daemon, with what it needs besides the flags."""
        return [
            ["info", "--server", address],
            ["models", "--server", address],
            ["distance", "--server", address, self.box],
            ["ccd", "--server", address, self.box, self.box],
            ["demo", "--server", address, "--frames", "1"],
            ["verify", "--server", address, "--model", "m", "--tolerance", "0"],
            ["review", "--server", address, "--model", "m", "--avatar", self.box, "--path",
             self.path],
            ["load", "--server", address, "--duration", "1s", "--warmup", "0"],
        ]

    def expect_error(self, p, code, *fragments):
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertEqual(p.stdout, "")
        self.assertRegex(p.stderr, rf"^proxima: error: {code}: ")
        for fragment in fragments:
            self.assertIn(fragment, p.stderr)

    def test_missing_token_file_on_every_server_command(self):
        missing = os.path.join(self.tmp, "no-such-token")
        for command in self.server_commands(self.nowhere):
            with self.subTest(command=command[0]):
                p = run(PROXIMA, *command, "--token-file", missing)
                self.expect_error(p, "NOT_FOUND", "--token-file", missing, "does not exist")

    def test_token_file_errors(self):
        p = run(PROXIMA, "info", "--server", self.nowhere, "--token-file", self.empty_token)
        self.expect_error(p, "INVALID_ARGUMENT", self.empty_token, "first line is empty")
        p = run(PROXIMA, "info", "--server", self.nowhere, "--token-file", self.tmp)
        self.expect_error(p, "INVALID_ARGUMENT", "is a directory")
        binary = self.write("binary-token", "tok\x01en\n", 0o600)
        p = run(PROXIMA, "info", "--server", self.nowhere, "--token-file", binary)
        self.expect_error(p, "INVALID_ARGUMENT", binary, "printable ASCII")
        if os.geteuid() != 0:  # root reads anything
            unreadable = self.write("unreadable-token", "tok\n", 0o000)
            p = run(PROXIMA, "info", "--server", self.nowhere, "--token-file", unreadable)
            self.expect_error(p, "FAILED_PRECONDITION", unreadable, "cannot be read")

    def test_bad_token_in_the_environment(self):
        p = run(PROXIMA, "info", "--server", self.nowhere, env={"PROXIMA_TOKEN": "a\nb"})
        self.expect_error(p, "INVALID_ARGUMENT", "token")

    def test_tls_file_errors(self):
        missing = os.path.join(self.tmp, "no-such-ca.pem")
        for command in self.server_commands(self.nowhere):
            with self.subTest(command=command[0]):
                p = run(PROXIMA, *command, "--tls-ca", missing)
                self.expect_error(p, "NOT_FOUND", missing)
        p = run(PROXIMA, "info", "--server", self.nowhere, "--tls-ca", self.not_pem)
        self.expect_error(p, "INVALID_ARGUMENT", self.not_pem, "no PEM certificate")
        p = run(PROXIMA, "info", "--server", self.nowhere, "--tls-cert", self.not_pem)
        self.expect_error(p, "INVALID_ARGUMENT", self.not_pem)
        p = run(PROXIMA, "info", "--server", self.nowhere, "--tls-key", self.not_pem)
        self.expect_error(p, "INVALID_ARGUMENT", self.not_pem, "no PEM private key")

    def test_flags_need_server_where_it_is_optional(self):
        for command in (["distance", self.box], ["ccd", self.box, self.box],
                        ["demo", "--frames", "1"]):
            for flag, value in (("--token-file", self.token), ("--tls-ca", self.not_pem),
                                ("--tls-server-name", "localhost")):
                with self.subTest(command=command[0], flag=flag):
                    p = run(PROXIMA, *command, flag, value)
                    self.assertNotEqual(p.returncode, 0, p.stdout)
                    self.assertIn("--server", p.stderr)

    @unittest.skipIf(shutil.which("openssl") is None, "no openssl to make a certificate")
    def test_tls_needs_both_client_cert_and_key(self):
        key = os.path.join(self.tmp, "client.key")
        cert = os.path.join(self.tmp, "client.crt")
        subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                        "ec_paramgen_curve:prime256v1", "-nodes", "-keyout", key, "-out", cert,
                        "-days", "1", "-subj", "/CN=proxima-test"], check=True,
                       capture_output=True)
        p = run(PROXIMA, "info", "--server", self.nowhere, "--tls-cert", cert)
        self.expect_error(p, "INVALID_ARGUMENT", "key")
        p = run(PROXIMA, "info", "--server", self.nowhere, "--tls-key", key)
        self.expect_error(p, "INVALID_ARGUMENT", "certificate")

    @unittest.skipIf(PROXIMAD is None, "no proximad given")
    def test_against_a_plaintext_daemon(self):
        daemon = Daemon()
        try:
            # A daemon that checks no tokens ignores one; the token file's mode is a warning.
            p = run(PROXIMA, "info", "--server", daemon.address, "--json", "--token-file",
                    self.token)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertNotIn("warning", p.stderr)
            info = json.loads(p.stdout)
            self.assertEqual(info["principal"], "")
            p = run(PROXIMA, "info", "--server", daemon.address, "--token-file", self.open_token)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertRegex(p.stderr, r"^proxima: warning: token file '.*open-token' is "
                                       r"readable by every user \(mode 0644\)")
            p = run(PROXIMA, "info", "--server", daemon.address,
                    env={"PROXIMA_TOKEN": "s3cret-token\n"})
            self.assertEqual(p.returncode, 0, p.stderr)
            # TLS towards a plaintext daemon: the handshake fails, and the message says TLS.
            if shutil.which("openssl"):
                key = os.path.join(self.tmp, "ca.key")
                ca = os.path.join(self.tmp, "ca.crt")
                subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                                "ec_paramgen_curve:prime256v1", "-nodes", "-keyout", key, "-out",
                                ca, "-days", "1", "-subj", "/CN=proxima-test-ca"], check=True,
                               capture_output=True)
                p = run(PROXIMA, "info", "--server", daemon.address, "--tls-ca", ca,
                        "--tls-server-name", "localhost")
                self.expect_error(p, "UNAVAILABLE", "cannot reach proximad", "TLS")
        finally:
            self.assertEqual(daemon.stop(), 0)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
