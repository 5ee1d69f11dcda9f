"""Helpers shared by the Python tests of the command-line tools (tests/cli, tests/clients).

Each test script puts tests/support on sys.path and imports what it needs:

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
    from cli_helpers import Daemon, box_mesh, run_program, strip_stats, write_off
"""
import os
import re
import signal
import subprocess
import tempfile
import threading


def run_program(*cmd, timeout=240, env=None):
    """Runs a command and returns its CompletedProcess (text output). A negative return code is a
    signal, a crash: never acceptable, so it fails the calling test at once. `env`: variables set
    on top of this process's environment; PROXIMA_TOKEN is never inherited (a token in the
    developer's shell would change what the commands under test see)."""
    full_env = dict(os.environ)
    full_env.pop("PROXIMA_TOKEN", None)
    full_env.update(env or {})
    p = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, env=full_env)
    assert p.returncode >= 0, f"{cmd[0]} crashed with signal {-p.returncode}: {p.stderr}"
    return p


def box_mesh(lo, hi):
    """An axis-aligned box as (vertices, triangles), outward-facing."""
    v = [(hi[0] if k & 1 else lo[0], hi[1] if k & 2 else lo[1], hi[2] if k & 4 else lo[2])
         for k in range(8)]
    f = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
         (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)]
    return v, f


def write_off(path, parts):
    """Writes the (vertices, triangles) parts as one OFF file, each part's indices shifted past
    the vertices of the parts before it. Coordinates are written with repr: exact doubles."""
    verts, faces = [], []
    for v, f in parts:
        base = len(verts)
        verts += v
        faces += [tuple(base + i for i in t) for t in f]
    with open(path, "w") as out:
        out.write(f"OFF\n{len(verts)} {len(faces)} 0\n")
        for p in verts:
            out.write(" ".join(repr(float(c)) for c in p) + "\n")
        for t in faces:
            out.write("3 " + " ".join(str(i) for i in t) + "\n")


def strip_stats(doc, more=()):
    """The answer without its statistics (and the top-level keys in `more`)."""
    return {k: v for k, v in doc.items() if k != "stats" and k not in more}


class Daemon:
    """proximad on a free loopback port; `address` comes from its first stdout line ("listening
    on HOST:PORT"). Its standard error is kept in a temporary file (`log()`)."""

    def __init__(self, proximad, *flags):
        self.stderr = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen([proximad, "--listen", "127.0.0.1:0", *flags],
                                     stdout=subprocess.PIPE, stderr=self.stderr, text=True)
        first = []
        reader = threading.Thread(target=lambda: first.append(self.proc.stdout.readline()))
        reader.daemon = True
        reader.start()
        reader.join(30)
        m = re.match(r"listening on (\S+:\d+)$", first[0].strip()) if first else None
        if not m:
            self.proc.kill()
            self.proc.wait()
            raise RuntimeError(f"proximad did not print 'listening on HOST:PORT' (got {first!r});"
                               f" stderr:\n{self.log()}")
        self.address = m.group(1)
        # Keep draining stdout so the daemon never blocks on a full pipe.
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()

    def log(self):
        self.stderr.seek(0)
        return self.stderr.read()

    def close(self):
        self.stderr.close()

    def stop(self):
        """SIGTERM, then the exit status (killed after 60 s: a hang is a failure too)."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return "hung after SIGTERM"
        finally:
            self.proc.stdout.close()
