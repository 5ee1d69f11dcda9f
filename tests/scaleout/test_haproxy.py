"""Three proximad behind HAProxy (deploy/haproxy/haproxy.cfg with this test's ports), on loopback.

Every client sends `x-proxima-route` (its route: here the scene's name); HAProxy hashes it
consistently. The test checks that every call of a route lands on one daemon (each scene is found
on exactly one daemon, and every later call of its client finds it), then SIGKILLs the daemon that
holds the most scenes: its clients get UNAVAILABLE (or NOT_FOUND, once HAProxy's health check has
moved their route to another daemon), re-create their scene through HAProxy on a surviving daemon
and go on with the same answers; the other clients see no error at all.

Skipped when haproxy is not installed (deploy/setup.sh installs Debian's haproxy).
"""

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import grpc
import numpy as np
import pytest

import proxima

PROXIMAD = os.environ.get("PROXIMAD", "")
PROXIMA = os.environ.get("PROXIMA", "")
SOURCE = Path(os.environ.get("PROXIMA_SOURCE_DIR", Path(__file__).resolve().parents[2]))
HAPROXY = shutil.which("haproxy") or (
    "/usr/sbin/haproxy" if os.access("/usr/sbin/haproxy", os.X_OK) else None)

pytestmark = pytest.mark.skipif(
    HAPROXY is None, reason="haproxy is not installed: run deploy/setup.sh --deps (Debian haproxy)")

ROUTES = [f"scene-{i:02d}" for i in range(12)]
DEADLINE_S = 20.0


def free_ports(n):
    """n distinct free loopback ports (bound to port 0, then released)."""
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def cube(name):
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                 dtype=np.uint32)
    return proxima.Mesh(name, v, t)


def gap_positions(gap):
    """The second cube's vertices `gap` beyond the first along x (unit cubes: distance = gap)."""
    return cube("b").vertices + np.array([1.0 + gap, 0, 0])


def start_daemon(workdir, index):
    log = open(workdir / f"proximad-{index}.log", "w+")
    proc = subprocess.Popen([PROXIMAD, "--listen", "127.0.0.1:0", "--metrics-listen",
                             "127.0.0.1:0", "--drain-seconds", "1"],
                            stdout=subprocess.PIPE, stderr=log, text=True)
    listen = re.fullmatch(r"listening on (\S+)\n", proc.stdout.readline())
    metrics = re.fullmatch(r"metrics on (\S+)\n", proc.stdout.readline())
    assert listen and metrics, f"proximad-{index} did not start: see {log.name}"
    return proc, listen.group(1), metrics.group(1)


def haproxy_config(template, front_port, stats_port, daemons):
    """The template with this test's frontend and servers, plus a stats page to poll."""
    text = re.sub(r"bind 127\.0\.0\.1:\d+ proto h2", f"bind 127.0.0.1:{front_port} proto h2",
                  template)
    text = re.sub(r"^    server .*\n", "", text, flags=re.M)
    servers = "".join(
        f"    server proximad-{i} {grpc_addr} check port {metrics.rsplit(':', 1)[1]}\n"
        for i, (_, grpc_addr, metrics) in enumerate(daemons))
    text = text.rstrip("\n") + "\n" + servers
    text = text.replace("    log stderr format raw local0 info\n", "")
    return text + (f"\nfrontend stats\n    bind 127.0.0.1:{stats_port}\n    stats enable\n"
                   f"    stats uri /stats\n")


def servers_up(stats_port):
    with urllib.request.urlopen(f"http://127.0.0.1:{stats_port}/stats;csv", timeout=2) as r:
        rows = r.read().decode().splitlines()
    header = rows[0].lstrip("# ").split(",")
    status = header.index("status")
    return {row.split(",")[1]: row.split(",")[status] for row in rows[1:]
            if row.startswith("proximad,") and not row.split(",")[1] == "BACKEND"}


def wait_until(predicate, what):
    end = time.monotonic() + DEADLINE_S
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def cluster():
    if not PROXIMAD:
        pytest.fail("PROXIMAD (the proximad binary) is not set")
    workdir = Path(tempfile.mkdtemp(prefix="proxima-haproxy-"))
    procs = []
    try:
        daemons = [start_daemon(workdir, i) for i in range(3)]
        procs += [d[0] for d in daemons]
        front, stats = free_ports(2)
        template = (SOURCE / "deploy/haproxy/haproxy.cfg").read_text()
        cfg = workdir / "haproxy.cfg"
        cfg.write_text(haproxy_config(template, front, stats, daemons))
        check = subprocess.run([HAPROXY, "-c", "-q", "-f", str(cfg)], capture_output=True,
                               text=True)
        assert check.returncode == 0, check.stdout + check.stderr
        hlog = open(workdir / "haproxy.log", "w+")
        procs.append(subprocess.Popen([HAPROXY, "-db", "-f", str(cfg)], stdout=hlog,
                                      stderr=subprocess.STDOUT))
        wait_until(lambda: _all_up(stats, 3), "HAProxy to see three healthy daemons")
        yield {"front": f"127.0.0.1:{front}", "stats": stats, "daemons": daemons}
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        shutil.rmtree(workdir, ignore_errors=True)


def _all_up(stats, n):
    try:
        up = servers_up(stats)
    except OSError:
        return False
    return sum(1 for s in up.values() if s == "UP") == n


def owners(direct, scene_id, route):
    """The daemons (indices) that hold scene `scene_id` named `route`."""
    found = []
    for i, c in enumerate(direct):
        if c is None:
            continue
        try:
            if c.describe_scene(scene_id).name == route:
                found.append(i)
        except proxima.ProximaError as e:
            assert e.code == grpc.StatusCode.NOT_FOUND, e
    return found


class Session:
    """One client of one scene through HAProxy: route = the scene's name."""

    def __init__(self, front, route):
        self.route = route
        self.client = proxima.Client(front, route=route, timeout=10)
        self.create()

    def create(self):
        self.scene = self.client.create_scene([cube("a"), cube("b")], name=self.route)
        self.b = self.scene.objects[1].id

    def query(self, gap):
        r = self.client.query(self.scene.scene_id, positions={self.b: gap_positions(gap)})
        return float(r.distances[0])


def test_routes_are_sticky_and_survive_a_daemon(cluster):
    direct = [proxima.Client(addr, timeout=10) for _, addr, _ in cluster["daemons"]]
    for _, _, metrics in cluster["daemons"]:
        with urllib.request.urlopen(f"http://{metrics}/healthz", timeout=2) as r:
            assert "proxima_serving 1" in r.read().decode()

    sessions = [Session(cluster["front"], route) for route in ROUTES]
    home = {}
    for s in sessions:
        where = owners(direct, s.scene.scene_id, s.route)
        assert len(where) == 1, f"{s.route} is on daemons {where}"
        home[s.route] = where[0]
    # Every later call of a route reaches the daemon that holds its scene (else NOT_FOUND).
    for step in range(3):
        for s in sessions:
            assert s.query(0.5 + step) == pytest.approx(0.5 + step)
    assert len(set(home.values())) >= 2, f"the consistent hash used one daemon only: {home}"
    for i, c in enumerate(direct):
        assert c.server_info().live_scenes == sum(1 for d in home.values() if d == i)

    victim = max(range(3), key=lambda i: sum(1 for d in home.values() if d == i))
    # One open frame stream on the victim and one on another daemon.
    streams = {}
    for s in sessions:
        side = home[s.route] == victim
        if side not in streams:
            stream = s.client.open_stream(timeout=10)
            streams[side] = (s, stream)
            stream.send(proxima.make_frame(scene_id=s.scene.scene_id,
                                           positions={s.b: gap_positions(0.5)}))
            assert float(stream.receive().distances[0]) == pytest.approx(0.5)
    cluster["daemons"][victim][0].send_signal(signal.SIGKILL)
    cluster["daemons"][victim][0].wait()
    direct[victim].close()
    direct[victim] = None

    lost = [s for s in sessions if home[s.route] == victim]
    kept = [s for s in sessions if home[s.route] != victim]
    assert lost and kept
    for s in kept:  # at once: no error for the other daemons' clients
        assert s.query(1.75) == pytest.approx(1.75)
    s, stream = streams[False]
    stream.send(proxima.make_frame(scene_id=s.scene.scene_id, positions={s.b: gap_positions(1.5)}))
    assert float(stream.receive().distances[0]) == pytest.approx(1.5)
    stream.close()
    # The victim's open stream ends. Through HAProxy that is CANCELLED ("Received RST_STREAM
    # with error code 8": HAProxy resets the client's stream when its server connection dies),
    # not the UNAVAILABLE a direct connection gives (docs/deploy.md).
    s, stream = streams[True]
    with pytest.raises(proxima.ProximaError) as ended:
        stream.send(proxima.make_frame(scene_id=s.scene.scene_id,
                                       positions={s.b: gap_positions(1.5)}))
        stream.receive()
    assert ended.value.code in (grpc.StatusCode.CANCELLED, grpc.StatusCode.UNAVAILABLE), ended.value
    # The victim's clients: the next call fails with UNAVAILABLE (HAProxy cannot reach the
    # daemon) or, once the health check has moved the route, NOT_FOUND (a daemon without it).
    codes = set()
    for s in lost:
        with pytest.raises(proxima.ProximaError) as failed:
            s.query(2.0)
        codes.add(failed.value.code)
    assert codes <= {grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.NOT_FOUND}, codes
    # Each re-creates its scene through HAProxy (retrying while its route still points at the
    # dead daemon) and goes on with the same answers.
    wait_until(lambda: _all_up(cluster["stats"], 2), "HAProxy to mark the killed daemon down")
    for s in lost:
        for _ in range(50):
            try:
                s.create()
                break
            except proxima.ProximaError as e:
                assert e.code == grpc.StatusCode.UNAVAILABLE, e
                time.sleep(0.1)
        else:
            raise AssertionError(f"{s.route} could not re-create its scene")
        where = owners(direct, s.scene.scene_id, s.route)
        assert len(where) == 1 and where[0] != victim, (s.route, where)
        home[s.route] = where[0]
    # Everyone goes on; the other daemons' clients never saw an error (a failure raises here),
    # and their routes did not move (consistent hashing moves only the dead daemon's keys).
    for step in range(3):
        for s in sessions:
            assert s.query(0.25 + step) == pytest.approx(0.25 + step)
    for s in kept:
        assert owners(direct, s.scene.scene_id, s.route) == [home[s.route]]
    for c in direct:
        if c is not None:
            c.close()
    for s in sessions:
        s.client.close()


def write_obj(path, mesh, offset):
    lines = [f"v {x + offset} {y} {z}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.triangles]
    path.write_text("\n".join(lines) + "\n")


def test_cli_calls_meet_on_one_daemon(cluster, tmp_path):
    """`proxima distance --server` makes three calls (CreateScene, Query, DeleteScene): without
    the CLI's own route they would be spread over the daemons and the Query would not find the
    scene. Run several times, so the random routes cover more than one daemon."""
    if not PROXIMA:
        pytest.fail("PROXIMA (the proxima binary) is not set")
    a, b = tmp_path / "a.obj", tmp_path / "b.obj"
    write_obj(a, cube("a"), 0.0)
    write_obj(b, cube("b"), 1.25)
    for _ in range(6):
        run = subprocess.run([PROXIMA, "distance", "--server", cluster["front"], "--json",
                              str(a), str(b)], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        assert "0.25" in run.stdout, run.stdout


def write_sequence(folder, gaps):
    """A sequence folder: frame k is two unit cubes `gaps[k]` apart along x (one OBJ, two
    components: play it with --split-components)."""
    folder.mkdir()
    a, b = cube("a"), cube("b")
    for k, gap in enumerate(gaps):
        lines = [f"v {x} {y} {z}" for x, y, z in a.vertices]
        lines += [f"v {x + 1.0 + gap} {y} {z}" for x, y, z in b.vertices]
        lines += [f"f {i + 1} {j + 1} {m + 1}" for i, j, m in a.triangles]
        lines += [f"f {i + 9} {j + 9} {m + 9}" for i, j, m in b.triangles]
        (folder / f"frame_{k:03d}.obj").write_text("\n".join(lines) + "\n")


def test_resilient_play_survives_its_daemon(cluster, tmp_path):
    """`proxima play --server HAPROXY --resilient` (a C++ ResilientScene) keeps playing when the
    daemon that holds its scene is SIGKILLed: through HAProxy its stream ends CANCELLED
    ("RST_STREAM error code 8"), which the session must take as "the daemon went away" like
    UNAVAILABLE; it re-creates the scene on a surviving daemon, re-sends the frames in flight, and
    every frame is answered exactly once, in order, with the answer a single daemon gives. A client
    of another daemon sees no error."""
    if not PROXIMA:
        pytest.fail("PROXIMA (the proxima binary) is not set")
    gaps = [0.25 + 0.01 * k for k in range(80)]
    seq = tmp_path / "seq"
    write_sequence(seq, gaps)
    out = tmp_path / "frames.jsonl"
    direct = [proxima.Client(addr, timeout=10) for _, addr, _ in cluster["daemons"]]
    play = subprocess.Popen([PROXIMA, "play", str(seq), "--split-components", "--server",
                             cluster["front"], "--resilient", "--fps", "20", "--in-flight", "2",
                             "--query", "separation", "--quiet", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # The daemon that holds the play's scene (the only scene of this cluster so far).
        victim = []
        wait_until(lambda: victim.extend(i for i, c in enumerate(direct)
                                         if c.server_info().live_scenes == 1) or victim,
                   "the play's scene to appear on a daemon")
        victim = victim[0]
        # A client of another daemon (its route chosen until it lands on one).
        other = None
        for n in range(40):
            s = Session(cluster["front"], f"other-{n:02d}")
            if owners(direct, s.scene.scene_id, s.route) != [victim]:
                other = s
                break
            s.client.delete_scene(s.scene.scene_id)
            s.client.close()
        assert other is not None, "no route landed on another daemon"
        wait_until(lambda: out.exists() and len(out.read_text().splitlines()) >= 10,
                   "the first ten frames")
        cluster["daemons"][victim][0].send_signal(signal.SIGKILL)
        cluster["daemons"][victim][0].wait()
        direct[victim].close()
        direct[victim] = None
        assert other.query(1.75) == pytest.approx(1.75)  # at once: no error
        stdout, stderr = play.communicate(timeout=60)
    finally:
        if play.poll() is None:
            play.kill()
            play.wait()
    print(stderr, file=sys.stderr)  # the summary: how many re-creations, after which failure
    assert play.returncode == 0, stderr
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [f["frame"] for f in lines] == list(range(len(gaps)))
    for f, gap in zip(lines, gaps):
        assert f["object_count"] == 2
        assert f["closest"]["distance"] == pytest.approx(gap), f
    # It was re-created (at least once: the scene was on the killed daemon), on a surviving
    # daemon, which the play then deleted it from: only the other client's scene is left.
    made = re.search(r"scene re-created (\d+) times", stderr)
    assert made and int(made.group(1)) >= 1, stderr
    assert sum(c.server_info().live_scenes for c in direct if c is not None) == 1  # other's
    assert other.query(0.5) == pytest.approx(0.5)
    other.client.close()
    for c in direct:
        if c is not None:
            c.close()


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
