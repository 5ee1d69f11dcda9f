#!/usr/bin/env python3
"""Tokens and TLS from the client side (issue #7), without depending on the daemon's
implementation: a fake Proximity service in this process (Python grpc) that answers
GetServerInfo with the authorization header it received as `principal` (UNAUTHENTICATED without
one), served over TLS with a certificate for IP:127.0.0.1 and DNS:localhost signed by a test CA,
and over mutual TLS. Both clients are checked against it: the Python client (token, tls_ca,
tls_cert/tls_key, tls_server_name) and the C++ library through `proxima info` (--token-file,
PROXIMA_TOKEN, --tls-ca, --tls-cert, --tls-key, --tls-server-name), including the failures: an
untrusted certificate, a name the certificate does not hold, a missing client certificate.

Usage: test_client_security.py --proxima PROXIMA
(run with an interpreter that has Debian's grpc, google.protobuf and numpy modules,
/usr/bin/python3, and the `proxima` package on PYTHONPATH: build/<preset>/python)."""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest
from concurrent import futures

parser = argparse.ArgumentParser()
parser.add_argument("--proxima", required=True)
ARGS, UNITTEST_ARGS = parser.parse_known_args()
# The fake service's handshake failures are expected here; gRPC would log each one.
os.environ.setdefault("GRPC_VERBOSITY", "NONE")

import grpc  # noqa: E402
import proxima as pc  # noqa: E402


class FakeProximity(pc.pb_grpc.ProximityServicer):
    def GetServerInfo(self, request, context):
        auth = dict(context.invocation_metadata()).get("authorization", "")
        if not auth:
            context.abort(grpc.StatusCode.UNAUTHENTICATED, "fake: no bearer token")
        return pc.pb.ServerInfo(version="fake", api="proxima.v1", principal=auth)


def openssl(*args):
    subprocess.run(["openssl", *args], check=True, capture_output=True)


def make_pki(folder):
    """A CA, a server certificate (SAN IP:127.0.0.1, DNS:localhost) and a client certificate
    signed by it, and a second CA that signed nothing here."""
    p = {name: os.path.join(folder, name) for name in
         ("ca.key", "ca.crt", "other-ca.key", "other-ca.crt", "server.key", "server.csr",
          "server.crt", "client.key", "client.csr", "client.crt", "san.ext")}
    for ca in ("ca", "other-ca"):
        openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", p[f"{ca}.key"],
                "-out", p[f"{ca}.crt"], "-days", "2", "-subj", f"/CN=proxima test {ca}")
    with open(p["san.ext"], "w") as f:
        f.write("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for who in ("server", "client"):
        openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", p[f"{who}.key"], "-out",
                p[f"{who}.csr"], "-subj", f"/CN=proxima test {who}")
        extra = ["-extfile", p["san.ext"]] if who == "server" else []
        openssl("x509", "-req", "-in", p[f"{who}.csr"], "-CA", p["ca.crt"], "-CAkey",
                p["ca.key"], "-CAcreateserial", "-out", p[f"{who}.crt"], "-days", "2", *extra)
    return p


def read(path):
    with open(path, "rb") as f:
        return f.read()


def serve(pki, mutual):
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    pc.pb_grpc.add_ProximityServicer_to_server(FakeProximity(), server)
    credentials = grpc.ssl_server_credentials(
        [(read(pki["server.key"]), read(pki["server.crt"]))],
        root_certificates=read(pki["ca.crt"]) if mutual else None,
        require_client_auth=mutual)
    port = server.add_secure_port("127.0.0.1:0", credentials)
    server.start()
    return server, f"127.0.0.1:{port}"


def run(*args, env=None):
    full_env = dict(os.environ)
    full_env.pop("PROXIMA_TOKEN", None)
    full_env.update(env or {})
    p = subprocess.run([ARGS.proxima, *args], capture_output=True, text=True, timeout=120,
                       env=full_env)
    assert p.returncode >= 0, f"proxima crashed with signal {-p.returncode}: {p.stderr}"
    return p


@unittest.skipIf(shutil.which("openssl") is None, "no openssl to make certificates")
class ClientSecurity(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="proxima-tls-")
        cls.pki = make_pki(cls.tmp)
        cls.token_file = os.path.join(cls.tmp, "token")
        with open(cls.token_file, "w") as f:
            f.write("tok-123\n")
        os.chmod(cls.token_file, 0o600)
        cls.tls, cls.tls_address = serve(cls.pki, mutual=False)
        cls.mtls, cls.mtls_address = serve(cls.pki, mutual=True)

    @classmethod
    def tearDownClass(cls):
        cls.tls.stop(None)
        cls.mtls.stop(None)
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_python_client_token_and_tls(self):
        with pc.Client(self.tls_address, token="tok-123", tls_ca=self.pki["ca.crt"]) as c:
            self.assertEqual(c.server_info().principal, "Bearer tok-123")
        with pc.Client(self.tls_address, tls_ca=self.pki["ca.crt"]) as c:
            with self.assertRaises(pc.ProximaError) as e:
                c.server_info()
            self.assertEqual(e.exception.code_name, "UNAUTHENTICATED")
        # The certificate holds DNS:localhost too: checking that name instead of the IP works.
        with pc.Client(self.tls_address, token="t", tls_ca=self.pki["ca.crt"],
                       tls_server_name="localhost") as c:
            self.assertEqual(c.server_info().principal, "Bearer t")
        with self.assertRaises(pc.ProximaError) as e:
            pc.Client(self.tls_address, connect_timeout=2, tls_ca=self.pki["other-ca.crt"])
        self.assertEqual(e.exception.code_name, "UNAVAILABLE")
        # Mutual TLS: with the client's certificate and key only.
        with pc.Client(self.mtls_address, token="m", tls_ca=self.pki["ca.crt"],
                       tls_cert=self.pki["client.crt"], tls_key=self.pki["client.key"]) as c:
            self.assertEqual(c.server_info().principal, "Bearer m")
        with self.assertRaises(pc.ProximaError) as e:
            pc.Client(self.mtls_address, connect_timeout=2, tls_ca=self.pki["ca.crt"])
        self.assertEqual(e.exception.code_name, "UNAVAILABLE")
        with self.assertRaises(pc.ProximaError) as e:
            pc.Client(self.tls_address, tls_ca=self.pki["ca.crt"], tls_cert=self.pki["client.crt"])
        self.assertEqual(e.exception.code_name, "INVALID_ARGUMENT")
        self.assertEqual(pc.read_token_file(self.token_file), "tok-123")
        with pc.Client(self.tls_address, token_file=self.token_file,
                       tls_ca=self.pki["ca.crt"]) as c:
            self.assertEqual(c.server_info().principal, "Bearer tok-123")

    def info(self, address, *flags, env=None):
        return run("info", "--server", address, "--json", *flags, env=env)

    def test_cli_token_and_tls(self):
        p = self.info(self.tls_address, "--tls-ca", self.pki["ca.crt"], "--token-file",
                      self.token_file)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(json.loads(p.stdout)["principal"], "Bearer tok-123")
        p = self.info(self.tls_address, "--tls-ca", self.pki["ca.crt"],
                      env={"PROXIMA_TOKEN": "env-token"})
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(json.loads(p.stdout)["principal"], "Bearer env-token")
        # --token-file wins over the environment.
        p = self.info(self.tls_address, "--tls-ca", self.pki["ca.crt"], "--token-file",
                      self.token_file, env={"PROXIMA_TOKEN": "env-token"})
        self.assertEqual(json.loads(p.stdout)["principal"], "Bearer tok-123")
        # No token: the service's UNAUTHENTICATED, printed with its name, exit 1.
        p = self.info(self.tls_address, "--tls-ca", self.pki["ca.crt"])
        self.assertEqual(p.returncode, 1)
        self.assertEqual(p.stderr, "proxima: error: UNAUTHENTICATED: fake: no bearer token\n")
        p = self.info(self.tls_address, "--tls-ca", self.pki["ca.crt"], "--tls-server-name",
                      "localhost", "--token-file", self.token_file)
        self.assertEqual(p.returncode, 0, p.stderr)

    def test_cli_tls_failures(self):
        # A name the certificate does not hold, a CA that did not sign it, plaintext towards TLS.
        for flags in (["--tls-ca", self.pki["ca.crt"], "--tls-server-name", "elsewhere.example"],
                      ["--tls-ca", self.pki["other-ca.crt"]],
                      []):
            with self.subTest(flags=flags):
                p = self.info(self.tls_address, "--token-file", self.token_file, *flags)
                self.assertEqual(p.returncode, 1, p.stdout)
                self.assertRegex(p.stderr, r"^proxima: error: UNAVAILABLE: cannot reach proximad")
                self.assertEqual(p.stdout, "")

    def test_cli_mutual_tls(self):
        p = self.info(self.mtls_address, "--tls-ca", self.pki["ca.crt"], "--tls-cert",
                      self.pki["client.crt"], "--tls-key", self.pki["client.key"],
                      "--token-file", self.token_file)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(json.loads(p.stdout)["principal"], "Bearer tok-123")
        p = self.info(self.mtls_address, "--tls-ca", self.pki["ca.crt"], "--token-file",
                      self.token_file)
        self.assertEqual(p.returncode, 1)
        self.assertRegex(p.stderr, r"^proxima: error: UNAVAILABLE: ")
        # A key that is not the certificate's: the handshake cannot succeed.
        p = self.info(self.mtls_address, "--tls-ca", self.pki["ca.crt"], "--tls-cert",
                      self.pki["client.crt"], "--tls-key", self.pki["server.key"],
                      "--token-file", self.token_file)
        self.assertEqual(p.returncode, 1)


if __name__ == "__main__":
    unittest.main(argv=[sys.argv[0], *UNITTEST_ARGS], verbosity=2)
