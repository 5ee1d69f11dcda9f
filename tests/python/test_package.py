"""The proxima package against a live proximad (conftest.py): scenes, uploads, every query and
culler against brute force, float32, CCD, penetration, streams and their cancellation, errors
with their status codes, massive models (list, verify, review rooms)."""
import json
import os
import re
import struct
import subprocess
import threading
import time
from pathlib import Path
from typing import Any, Iterator, Set, Tuple

import grpc
import numpy as np
import pytest

import proxima
from conftest import Daemon, box_mesh, local_verify, tool, write_off

A = proxima.box("a", (0, 0, 0), (1, 1, 1))
B = proxima.box("b", (1.5, 0, 0), (2.5, 1, 1))


def test_server_info(client: proxima.Client) -> None:
    info = client.server_info()
    assert info.api == "proxima.v1"
    assert info.limits.max_frames_in_flight > 0
    assert info.gpu_active or info.gpu_fallback_reason


def test_route(daemon: Daemon) -> None:
    """Every Client has a route (docs/deploy.md): its own random key unless one is given."""
    with proxima.Client(daemon.address) as a, proxima.Client(daemon.address) as b:
        assert re.fullmatch(r"client-[0-9a-f]{16}", a.route) and a.route != b.route
    with proxima.Client(daemon.address, route="scene-7") as c:
        assert c.route == "scene-7"
        assert c.server_info().api == "proxima.v1"  # the daemon ignores the header
    for bad in ("", "caf\u00e9", "a\nb"):
        with pytest.raises(proxima.ProximaError) as e:
            proxima.Client(daemon.address, route=bad)
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT
    assert proxima.ROUTE_HEADER == "x-proxima-route"


def test_room_calls_are_routed_by_the_room(daemon: Daemon) -> None:
    """A region snapshot of a review room goes where the room's members meet: routed by the
    room's name (as fetch_region and review), unless the Client was given a route."""
    seen = []

    class Recorder:
        def Snapshot(self, request: Any, timeout: Any = None, metadata: Any = None) -> Any:
            seen.append(dict(metadata)[proxima.ROUTE_HEADER])
            return request

    with proxima.Client(daemon.address) as c, \
            proxima.Client(daemon.address, route="mine") as routed:
        for client in (c, routed):
            client.stub = Recorder()
            client.snapshot_region("plant", room="hall-2")
            client.snapshot_region("plant")
            client.snapshot("scene-1")
        assert seen == ["hall-2", c.route, c.route, "mine", "mine", "mine"]


def test_scene_lifecycle_and_numpy_results(client: proxima.Client) -> None:
    scene = client.create_scene([A, B], name="pair")
    try:
        assert [o.triangle_count for o in scene.objects] == [12, 12]
        described = client.describe_scene(scene.scene_id)
        assert described.name == "pair" and [o.name for o in described.objects] == ["a", "b"]
        result = client.query(scene.scene_id, collisions=True)
        np.testing.assert_array_equal(result.distances, [0.5, 0.5])
        np.testing.assert_array_equal(result.closest_objects, [1, 0])
        points = result.closest_points
        assert points.shape == (2, 2, 3)
        np.testing.assert_array_equal(points[0, :, 0], [1.0, 1.5])  # x on a, on b
        assert result.collision_pairs.shape == (0, 4)
        assert result.ids.tolist() == [o.id for o in scene.objects]
        # The proto stays readable through the result.
        assert result.separation[0].distance == 0.5 and result.raw.stats.culler
        # New positions as a numpy array: b moves 0.25 towards a.
        moved = B.vertices - [0.25, 0, 0]
        result = client.query(scene.scene_id, frame=1, positions={scene.objects[1].id: moved})
        assert result.frame == 1 and result.distances[0] == 0.25
        assert client.describe_scene(scene.scene_id).frames == 2
    finally:
        client.delete_scene(scene.scene_id)
    with pytest.raises(proxima.ProximaError) as e:
        client.describe_scene(scene.scene_id)
    assert e.value.code == grpc.StatusCode.NOT_FOUND and e.value.code_name == "NOT_FOUND"


def test_snapshot(client: proxima.Client) -> None:
    """Snapshot: a PNG of the asked size; bad sizes are INVALID_ARGUMENT, an unknown scene
    NOT_FOUND (the pixels are checked by tests/engine/render/test_snapshot.cpp)."""
    scene = client.create_scene([A, B])
    try:
        try:
            shot = client.snapshot(scene.scene_id, width=40, height=30, tolerance=0.6,
                                   camera=((0.5, -8, 0.5), (0.5, 0, 0.5), None, 40))
        except proxima.ProximaError as e:
            if e.code_name == "UNAVAILABLE" and not os.environ.get("CI"):
                pytest.skip(f"no EGL context here: {e.details}")
            raise
        assert shot.png[:8] == b"\x89PNG\r\n\x1a\n"
        assert (shot.width, shot.height) == (40, 30)
        assert struct.unpack(">II", shot.png[16:24]) == (40, 30)
        assert shot.tolerance_count > 0 and shot.collision_count == 0
        assert shot.camera.eye.y == -8 and shot.camera.up.z == 1
        for w, h in ((0, 10), (5000, 10)):
            with pytest.raises(proxima.ProximaError) as e:
                client.snapshot(scene.scene_id, width=w, height=h)
            assert e.value.code_name == "INVALID_ARGUMENT"
    finally:
        client.delete_scene(scene.scene_id)
    with pytest.raises(proxima.ProximaError) as e:
        client.snapshot("no-such-scene", width=8, height=8)
    assert e.value.code_name == "NOT_FOUND"


def test_errors_carry_the_status_code(client: proxima.Client) -> None:
    with pytest.raises(proxima.ProximaError) as e:
        client.query("no-such-scene")
    assert e.value.code is grpc.StatusCode.NOT_FOUND
    assert "no-such-scene" in e.value.details and str(e.value).startswith("NOT_FOUND: ")
    bad = proxima.Mesh("bad", A.vertices, [[0, 1, 40]])
    with pytest.raises(proxima.ProximaError) as e:
        client.create_scene([bad])
    assert e.value.code is grpc.StatusCode.INVALID_ARGUMENT and "40" in e.value.details
    scene = client.create_scene([A, B])
    try:
        with pytest.raises(proxima.ProximaError) as e:
            client.query(scene.scene_id, tolerance=-1.0)
        assert e.value.code_name == "INVALID_ARGUMENT"
        with pytest.raises(proxima.ProximaError) as e:
            client.query(scene.scene_id, positions={scene.objects[0].id: A.vertices[:3]})
        assert e.value.code_name == "INVALID_ARGUMENT"
        # Nothing changed: a rejected frame leaves the scene as it was.
        assert client.describe_scene(scene.scene_id).frames == 0
    finally:
        client.delete_scene(scene.scene_id)
    # Client-side checks: a ValueError before anything is sent.
    with pytest.raises(ValueError) as v:
        proxima.make_frame(culler="octree")
    for name in ("auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu"):
        assert name in str(v.value)
    with pytest.raises(ValueError):
        proxima.Mesh("flat", [[0, 0], [1, 1]], [[0, 1, 1]])
    with pytest.raises(ValueError):
        proxima.Mesh("neg", A.vertices, [[0, -1, 2]])
    with pytest.raises(proxima.ProximaError) as e:
        proxima.Client("127.0.0.1:1", connect_timeout=0.5)
    assert e.value.code is grpc.StatusCode.UNAVAILABLE


def test_culler_names() -> None:
    assert list(proxima.CULLERS) == ["auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu"]
    assert proxima.culler_value("VORONOI_CPU") == proxima.pb.CULLER_VORONOI_CPU
    assert proxima.culler_value("CULLER_BVH") == proxima.pb.CULLER_BVH
    assert proxima.culler_value(proxima.pb.CULLER_VORONOI_GPU) == proxima.pb.CULLER_VORONOI_GPU
    with pytest.raises(ValueError):
        proxima.culler_value(17)


def pair_set(pairs: np.ndarray, distances: Any = None) -> Set[Tuple[Any, ...]]:
    rows = [tuple(int(x) for x in r) for r in pairs]
    if distances is None:
        return set(rows)
    return {r + (float(d),) for r, d in zip(rows, distances)}


def test_every_culler_equals_brute_force(client: proxima.Client) -> None:
    # Boxes apart, touching and crossing, and a wavy grid above them: every query kind.
    rng = np.random.default_rng(7)
    sheet = proxima.grid("sheet", 12, origin=(-0.5, -0.5, 1.05), size=5.0)
    sheet.vertices[:, 2] += 0.05 * rng.random(len(sheet.vertices))
    meshes = [A, B, proxima.box("touching", (1, 0.25, 0.25), (1.5, 0.75, 0.75)),
              proxima.box("crossing", (0.5, 0.5, 0.5), (1.3, 1.3, 1.3)),
              proxima.box("far", (4, 4, 0), (5, 5, 1)), sheet]
    scene = client.create_scene(meshes)
    try:
        queries = dict(self_query=True, collisions=True, tolerance=0.3, pns=True)
        ref = client.query(scene.scene_id, culler="brute", **queries)
        assert len(ref.collisions) > 0 and len(ref.tolerance) > len(ref.collisions)
        gpu = client.server_info().gpu_active
        for name in proxima.CULLERS:
            try:
                r = client.query(scene.scene_id, culler=name, **queries)
            except proxima.ProximaError as e:
                # A daemon whose GPU never started refuses voronoi-gpu with this code.
                if name == "voronoi-gpu" and not gpu and \
                        e.code is grpc.StatusCode.FAILED_PRECONDITION:
                    continue
                raise
            np.testing.assert_array_equal(r.distances, ref.distances, err_msg=name)
            assert pair_set(r.collision_pairs) == pair_set(ref.collision_pairs), name
            assert pair_set(r.tolerance_pairs, r.tolerance_distances) == \
                pair_set(ref.tolerance_pairs, ref.tolerance_distances), name
            # The PNS is each culler's candidate set (docs/algorithms.md): it differs between
            # cullers but always holds every pair within the tolerance.
            assert pair_set(ref.tolerance_pairs) <= pair_set(r.pns_pairs), name
            for i in range(len(meshes)):
                np.testing.assert_array_equal(r.self_distances(i), ref.self_distances(i),
                                              err_msg=f"{name} self {i}")
        cell = client.query(scene.scene_id, culler="voronoi-cpu", voronoi_cell=0.25, **queries)
        np.testing.assert_array_equal(cell.distances, ref.distances)
        assert cell.stats.dvd_cell == 0.25
    finally:
        client.delete_scene(scene.scene_id)


def test_self_points(client: proxima.Client) -> None:
    scene = client.create_scene([proxima.box("a", (0, 0, 0), (1, 2, 3))])
    try:
        r = client.query(scene.scene_id, self_query=True, self_points=True)
        points = r.self_points(0)
        assert points.shape == (12, 2, 3)
        gaps = np.linalg.norm(points[:, 0] - points[:, 1], axis=1)
        np.testing.assert_allclose(gaps, r.self_distances(0))
        assert r.self_closest(0).shape == (12,)
        assert np.isinf(r.distances[0]) and r.closest_objects[0] == -1  # alone
    finally:
        client.delete_scene(scene.scene_id)


def test_float32_vertices(daemon: Any, client: proxima.Client) -> None:
    a32 = proxima.box("a", (0, 0, 0), (1, 1, 1), float32=True)
    assert a32.vertices.dtype == np.float32
    assert proxima.encode_mesh(a32).vertices.type == proxima.pb.SCALAR_TYPE_FLOAT32
    scene = client.create_scene([a32, B])
    try:
        assert client.query(scene.scene_id).distances[0] == 0.5
        moved = (B.vertices - [0.125, 0, 0]).astype(np.float32)
        r = client.query(scene.scene_id, frame=1, positions={scene.objects[1].id: moved})
        assert r.distances[0] == 0.375
    finally:
        client.delete_scene(scene.scene_id)
    with proxima.Client(daemon.address, float32=True) as c32:
        scene = c32.create_scene([A, B])
        try:
            assert c32.query(scene.scene_id).distances[0] == 0.5
        finally:
            c32.delete_scene(scene.scene_id)
    buffer = proxima.pack_vertices(a32.vertices)
    np.testing.assert_array_equal(proxima.unpack_vertices(buffer), a32.vertices)
    assert proxima.unpack_vertices(buffer).dtype == np.float32


def test_ccd(client: proxima.Client) -> None:
    small = proxima.box("small", (2, 0.25, 0.25), (2.5, 0.75, 0.75))
    scene = client.create_scene([A, small])
    try:
        # The small box sweeps from x in [2, 2.5] to [-1, -0.5]: it meets x = 1 at t = 1/3.
        r = client.query(scene.scene_id, frame=1, separation=False, ccd=True,
                         positions={scene.objects[1].id: small.vertices - [3, 0, 0]})
        earliest = r.ccd_earliest
        assert earliest is not None and 1 / 3 - 1e-5 < earliest.toi <= 1 / 3
        assert r.ccd_pairs.shape == (len(r.ccd.pairs), 5) and len(r.ccd.object_pairs) == 1
        assert r.ccd_toi.min() == earliest.toi
        # Every pair names its primitives' vertices in the uploaded buffers' numbering.
        meshes = [A, small]
        assert r.ccd_vertices.shape == (len(r.ccd.pairs), 2, 3)
        kinds = set()
        for (kind, _, prim, other, other_prim), (mine, theirs) in zip(r.ccd_pairs, r.ccd_vertices):
            kinds.add(int(kind))
            if kind == proxima.pb.CCD_VERTEX_FACE:
                assert list(mine) == [prim, -1, -1]
                assert list(theirs) == list(meshes[other].triangles[other_prim])
            else:
                assert mine[0] < mine[1] and theirs[0] < theirs[1] and mine[2] == theirs[2] == -1
        assert kinds == {0, 1}
        # Back where it started, but with a minimum distance of 0.1 in a short move: no contact.
        r = client.query(scene.scene_id, frame=2, separation=False, ccd=True,
                         ccd_min_distance=0.1, positions={scene.objects[1].id: small.vertices})
        assert r.ccd_earliest is not None  # sweeps back through a
        r = client.query(scene.scene_id, frame=3, separation=False, ccd=True,
                         positions={scene.objects[1].id: small.vertices + [1, 0, 0]})
        assert r.ccd_earliest is None and r.ccd_pairs.shape == (0, 5)
    finally:
        client.delete_scene(scene.scene_id)


def test_penetration(client: proxima.Client) -> None:
    crossing = proxima.box("crossing", (0.5, 0.5, 0.5), (1.5, 1.5, 1.5))
    scene = client.create_scene([A, crossing])
    try:
        r = client.query(scene.scene_id, penetration=True)
        assert r.penetration_objects.tolist() == [[0, 1]]
        assert r.penetration_depths[0] > 0 and r.penetration_vectors.shape == (1, 3)
        assert len(r.collision_pairs) > 0  # implied
        # Moving a by the vector separates the pair locally.
        v = r.penetration_vectors[0]
        np.testing.assert_allclose(np.linalg.norm(v), r.penetration_depths[0])
    finally:
        client.delete_scene(scene.scene_id)


def test_upload_of_a_large_mesh(client: proxima.Client) -> None:
    # 52K vertices, 102K triangles: both buffers take two 1 MiB chunks.
    sheet = proxima.grid("sheet", 227, origin=(0, 0, 1.1), size=1.0)
    client.inline_mesh_bytes = 0
    scene = client.create_scene([sheet, A])
    try:
        assert [o.triangle_count for o in scene.objects] == [2 * 227 * 227, 12]
        assert client.query(scene.scene_id).distances[0] == pytest.approx(0.1, abs=1e-12)
        # Small chunks through upload_object directly.
        obj = client.upload_object(scene.scene_id, B, chunk_bytes=40)
        assert obj.triangle_count == 12
        assert len(client.describe_scene(scene.scene_id).objects) == 3
    finally:
        client.inline_mesh_bytes = 1 << 20
        client.delete_scene(scene.scene_id)


def test_streams_pipelined_and_lockstep(client: proxima.Client) -> None:
    scene = client.create_scene([A, B])
    b_id = scene.objects[1].id

    def frames() -> Iterator[Any]:
        for k in range(1, 5):
            yield proxima.make_frame(scene_id=scene.scene_id, frame=k,
                                     positions={b_id: B.vertices - [0.1 * k, 0, 0]})

    try:
        results = list(client.stream(frames()))
        assert [r.frame for r in results] == [1, 2, 3, 4]
        np.testing.assert_allclose([r.distances[0] for r in results], [0.4, 0.3, 0.2, 0.1])
    finally:
        client.delete_scene(scene.scene_id)
    # A stream-owned scene: ids from the first result, a topology change, a removal.
    with client.open_stream() as s:
        first = s.query(proxima.make_frame(additions=[A, B]))
        a_id, b_id = first.added_ids
        halves = [proxima.box("b0", (1.5, 0, 0), (2, 1, 1)),
                  proxima.box("b1", (2, 0, 0), (3, 1, 1))]
        second = s.query(proxima.make_frame(frame=1, topology_changes={b_id: halves}))
        new_ids = proxima.fragment_ids(second)[0]
        assert len(new_ids) == 2 and second.distances.tolist() == [0.5, 0.0, 0.0]
        third = s.query(proxima.make_frame(frame=2, removals=[int(new_ids[0])]))
        assert third.ids.tolist() == [a_id, new_ids[1]] and third.distances[0] == 1.0
    # A bad frame ends the stream with its status.
    s = client.open_stream()
    s.send(proxima.make_frame(additions=[A]))
    s.receive()
    s.send(proxima.make_frame(frame=1, removals=[12345]))
    with pytest.raises(proxima.ProximaError) as e:
        s.receive()
    assert e.value.code is grpc.StatusCode.NOT_FOUND and "12345" in e.value.details
    s.close()  # the error was raised already: closing does not raise it again
    # Unread, an error surfaces on close().
    s = client.open_stream()
    s.send(proxima.make_frame(scene_id="no-such-scene"))
    with pytest.raises(proxima.ProximaError) as e:
        s.close()
    assert e.value.code is grpc.StatusCode.NOT_FOUND


def test_stream_cancellation(client: proxima.Client) -> None:
    live = client.server_info().live_streams
    s = client.open_stream()
    s.send(proxima.make_frame(additions=[A, B]))
    assert s.receive().distances[0] == 0.5
    s.cancel()
    with pytest.raises(proxima.ProximaError) as e:
        s.receive()
    assert e.value.code is grpc.StatusCode.CANCELLED
    with pytest.raises(proxima.ProximaError):
        s.send(proxima.make_frame(frame=1))
    # A generator stream cancelled while the generator waits.
    release = threading.Event()

    def frames() -> Iterator[Any]:
        yield proxima.make_frame(additions=[A, B])
        release.wait(30)

    results = client.stream(frames())
    assert next(results).distances[0] == 0.5
    results.cancel()
    with pytest.raises(proxima.ProximaError) as e:
        next(results)
    assert e.value.code is grpc.StatusCode.CANCELLED
    release.set()
    for _ in range(100):  # the daemon notices the cancellations
        if client.server_info().live_streams == live:
            break
        time.sleep(0.05)
    assert client.server_info().live_streams == live


def test_models_and_verify(client: proxima.Client, models: Path) -> None:
    listed = client.list_models()
    assert [m.name for m in listed.models] == ["row"] and listed.models_dir
    row = listed.models[0]
    assert row.objects == 7 and row.pieces > 7
    progress = []
    result = client.verify("row", tolerance=0.1, on_progress=progress.append)
    reference = local_verify(models / "row", 0.1)
    assert [(p.name_a, p.name_b, p.triangle_a, p.triangle_b, p.distance)
            for p in result.pairs] == \
        [(p["name"], p["other_name"], p["triangle"], p["other_triangle"], p["distance"])
         for p in reference]
    assert result.summary.pairs_found == len(result.pairs) > 0
    assert result.object_pairs.shape == (len(result.pairs), 2)
    assert (result.object_pairs[:, 0] < result.object_pairs[:, 1]).all()
    assert result.points.shape == (len(result.pairs), 2, 3)
    np.testing.assert_array_equal(
        np.linalg.norm(result.points[:, 0] - result.points[:, 1], axis=1) <= 0.1 + 1e-12, True)
    assert progress and progress[-1].step
    # Event by event, then errors.
    kinds = [e.WhichOneof("event") for e in client.verify_model("row", 0.0)]
    assert kinds[-1] == "summary" and "pair" in kinds
    with pytest.raises(proxima.ProximaError) as e:
        client.verify("nope")
    assert e.value.code is grpc.StatusCode.NOT_FOUND
    with pytest.raises(proxima.ProximaError) as e:
        client.verify("row", tolerance=-1)
    assert e.value.code is grpc.StatusCode.INVALID_ARGUMENT
    stream = client.verify_model("row", 0.1)
    next(stream)
    stream.cancel()
    with pytest.raises(proxima.ProximaError) as e:
        list(stream)
    assert e.value.code is grpc.StatusCode.CANCELLED


def test_fetch_region(client: proxima.Client) -> None:
    row = client.list_models().models[0]
    # The whole model: every stored triangle once, by (object, triangle id), ordered by object.
    whole = client.fetch_region("row", float64=True).result()
    assert whole.summary.pieces == row.pieces == len(whole.pieces)
    assert whole.summary.triangles == row.triangles and not whole.summary.truncated
    ids = [(obj, int(t)) for obj, mesh, tri_ids in whole.meshes() for t in tri_ids]
    assert len(ids) == len(set(ids)) == row.triangles
    assert [p.object for p in whole.pieces] == sorted(p.object for p in whole.pieces)
    for obj, mesh, tri_ids in whole.meshes():
        assert mesh.vertices.dtype == np.float64 and len(tri_ids) == len(mesh.triangles)
    # Near a point: nearest first, every distance within the radius, float32 by default.
    kinds = [e.WhichOneof("event") for e in client.fetch_region("row", (0.5, 0.5, 0.5), 1.5)]
    assert kinds[0] == "piece" and kinds[-1] == "summary"
    near = client.fetch_region("row", (0.5, 0.5, 0.5), 1.5).result()
    distances = [p.distance for p in near.pieces]
    assert distances == sorted(distances) and 0 < len(distances) < row.pieces
    assert all(d <= 1.5 for d in distances) and distances[0] == 0.0
    assert near.meshes()[0][1].vertices.dtype == np.float32
    # Errors, before any event.
    for kwargs, code in [({"model": "nope"}, grpc.StatusCode.NOT_FOUND),
                         ({"model": "row", "radius": -1.0}, grpc.StatusCode.INVALID_ARGUMENT),
                         ({"model": "row", "objects": [99]}, grpc.StatusCode.INVALID_ARGUMENT),
                         ({"model": "row", "room": "none"}, grpc.StatusCode.NOT_FOUND)]:
        with pytest.raises(proxima.ProximaError) as e:
            list(client.fetch_region(**kwargs))
        assert e.value.code is code, kwargs


def test_snapshot_region(client: proxima.Client) -> None:
    """Snapshot of a model region: the pieces FetchRegion selects, drawn with their touching
    pairs; exactly one of scene_id and model; the region's errors."""
    near = client.fetch_region("row", (0.5, 0.5, 0.5), 1.5).result()
    try:
        shot = client.snapshot_region("row", (0.5, 0.5, 0.5), 1.5, width=40, height=30)
    except proxima.ProximaError as e:
        if e.code_name == "UNAVAILABLE" and not os.environ.get("CI"):
            pytest.skip(f"no EGL context here: {e.details}")
        raise
    assert shot.png[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", shot.png[16:24]) == (40, 30)
    assert shot.region.pieces == near.summary.pieces
    assert shot.region.triangles == near.summary.triangles
    assert shot.region.objects == len({p.object for p in near.pieces})
    assert shot.collision_count > 0  # boxes 0 and 1 touch
    for kwargs, code in [({"model": "nope"}, "NOT_FOUND"),
                         ({"model": "row", "radius": -1.0}, "INVALID_ARGUMENT"),
                         ({"model": "row", "room": "none"}, "NOT_FOUND"),
                         ({"model": ""}, "INVALID_ARGUMENT")]:
        with pytest.raises(proxima.ProximaError) as e:
            client.snapshot_region(width=8, height=8, **kwargs)
        assert e.value.code_name == code, kwargs


def test_review_room(client: proxima.Client) -> None:
    avatar = proxima.box("avatar", (-0.1, -0.1, -0.1), (0.1, 0.1, 0.1))
    with client.review("room-1", "row", "ann", avatar, tolerance=0.2) as ann:
        assert ann.joined.model == "row" and [m.name for m in ann.joined.members] == ["ann"]
        stored = ann.joined.object_count
        # Across the face x = 1 of box-0 (x in [0, 1]) at mid height: a collision with it.
        hit = ann.pose((1.0, 0.5, 0.5))
        names = [h.object_name for h in hit.collisions]
        assert any("box-0" in n for n in names), names
        assert hit.sequence == 1 and hit.nearest.distance == 0.0
        with client.review("room-1", "row", "bob", avatar) as bob:
            assert ann.next_event(10, "member_joined").member_joined.member == "bob"
            assert sorted(m.name for m in bob.joined.members) == ["ann", "bob"]
            far = bob.pose(np.array([[1, 0, 0, 0.5], [0, 1, 0, 0.5], [0, 0, 1, 20.0]]))
            assert len(far.collisions) == 0 and far.nearest.distance > 18
            peer = ann.next_event(10, "peer")
            assert peer.WhichOneof("event") == "peer" and peer.peer.member == "bob"
            np.testing.assert_array_equal(proxima.transform_matrix(peer.peer.transform)[:, 3],
                                          [0.5, 0.5, 20.0])
            # While ann only poses, bob's updates she passes are held coalesced: his newest.
            last = [bob.pose((0.5, 0.5, 20.0 + 0.01 * k)).sequence for k in range(30)][-1]
            ann.pose((1.0, 0.5, 0.5))
            latest = [ann.next_event(10, "peer").peer.sequence]
            while latest[-1] != last:  # bob's last update may come after ann's answer
                latest.append(ann.next_event(10, "peer").peer.sequence)
            assert len(latest) <= 2, latest
            bob.pose((0.5, 0.5, 20.0))
            # Edits: bob adds a box across his avatar; both see it; it collides with the avatar.
            added = bob.add(proxima.box("crate", (0.55, 0.3, 19.8), (0.95, 0.7, 20.2)))
            assert added.object == stored and added.model_version == 1
            seen = ann.next_event(10, "edit_applied").edit_applied
            assert (seen.member, seen.object_name, seen.what) == \
                ("bob", "crate", proxima.pb.EDIT_ADD)
            assert [h.object_name for h in bob.pose((0.5, 0.5, 20.0)).collisions] == ["crate"]
            bob.remove(added.object)
            assert ann.next_event(10, "edit_applied").edit_applied.what == proxima.pb.EDIT_DELETE
            # A taken member name, an unknown model: errors that end that stream only.
            with pytest.raises(proxima.ProximaError) as e:
                client.review("room-1", "row", "bob", avatar)
            assert e.value.code is grpc.StatusCode.FAILED_PRECONDITION
            with pytest.raises(proxima.ProximaError) as e:
                bob.remove(12345)
            assert e.value.code is grpc.StatusCode.NOT_FOUND
        assert ann.next_event(10, "member_left").member_left.member == "bob"
    with pytest.raises(proxima.ProximaError) as e:
        client.review("room-2", "nope", "ann", avatar)
    assert e.value.code is grpc.StatusCode.NOT_FOUND
    # Cancelling a member's stream: it leaves; reads then raise CANCELLED.
    cy = client.review("room-3", "row", "cy", avatar)
    cy.cancel()
    with pytest.raises(proxima.ProximaError) as e:
        cy.next_event(10)
    assert e.value.code is grpc.StatusCode.CANCELLED


def test_geometry_helpers() -> None:
    mesh = proxima.grid("g", 3, origin=(1, 2, 3), size=2.0)
    assert mesh.vertices.shape == (16, 3) and mesh.triangles.shape == (18, 3)
    assert mesh.triangles.dtype == np.uint32 and mesh.vertices.dtype == np.float64
    back = proxima.decode_mesh(proxima.encode_mesh(mesh))
    assert back.name == "g"
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.triangles, mesh.triangles)
    as32 = proxima.decode_mesh(proxima.encode_mesh(mesh, float32=True))
    assert as32.vertices.dtype == np.float32
    moved = mesh.translated((1, 0, 0), name="h")
    np.testing.assert_array_equal(moved.vertices[:, 0], mesh.vertices[:, 0] + 1)
    # Lists in, arrays out; transforms from a translation, a (3, 4) or (4, 4) matrix, 12 numbers.
    assert proxima.Mesh("l", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)]).triangles.shape \
        == (1, 3)
    t = proxima.transform((1, 2, 3))
    np.testing.assert_array_equal(proxima.transform_matrix(t), np.hstack([np.eye(3),
                                                                          [[1], [2], [3]]]))
    assert proxima.transform(np.eye(4)).m == proxima.transform(np.eye(4)[:3].ravel()).m
    with pytest.raises(ValueError):
        proxima.transform((1, 2))
    with pytest.raises(ValueError):
        proxima.Mesh("f", [(0, 0, 0)], [(0.5, 0, 0)])  # float indices


def test_review_cli_member_names(client: proxima.Client, daemon: Daemon,
                                 tmp_path: Path) -> None:
    """`proxima review --server`: a member name taken in the room is exit 1 with a hint to pass
    --member; the default name is USER@HOST-PID, so two clients without --member both join."""
    avatar_file, path_file = tmp_path / "avatar.off", tmp_path / "path.txt"
    write_off(str(avatar_file), [box_mesh((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1))])
    path_file.write_text("".join(f"{0.5 + 0.1 * k}, 0.5, 0.5\n" for k in range(40)))
    review = [tool("proxima"), "review", "--server", daemon.address, "--model", "row",
              "--room", "room-cli", "--avatar", str(avatar_file), "--path", str(path_file),
              "--tolerance", "0.1", "--quiet"]
    avatar = proxima.box("avatar", (-0.1, -0.1, -0.1), (0.1, 0.1, 0.1))
    with client.review("room-cli", "row", "dana", avatar):
        p = subprocess.run(review + ["--member", "dana"], capture_output=True, text=True,
                           timeout=120)
        assert p.returncode == 1, p.stderr
        assert "dana" in p.stderr and "--member NAME" in p.stderr, p.stderr
        assert p.stdout == ""
        # Two clients at once with the default name: both join, under different names.
        runs = [subprocess.Popen(review, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                 text=True) for _ in range(2)]
        outs = [r.communicate(timeout=120) for r in runs]
        for r, (out, err) in zip(runs, outs):
            assert r.returncode == 0, err
        names = [json.loads(out)["member"] for out, _ in outs]
        assert names[0] != names[1], names
        for name in names:
            assert re.fullmatch(r"[^@\s]+@[^@\s]+-\d+", name), name
