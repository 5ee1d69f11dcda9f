"""The connection to proximad and its calls: scenes, frames, massive models, review rooms."""
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import (Any, Callable, Iterable, Iterator, List, Optional, Sequence, Tuple, TypeVar,
                    Union)

import grpc
import numpy as np

from ._pb import proxima_pb2 as pb
from ._pb import proxima_pb2_grpc as pb_grpc
from .errors import ProximaError
from .frames import Result, make_frame
from .geometry import (ArrayLike, Mesh, decode_mesh, encode_mesh, pack_triangles, pack_vertices,
                       transform)

UPLOAD_CHUNK_BYTES = 1 << 20
T = TypeVar("T")
_END = object()  # the end of a request queue


def _call(fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    try:
        return fn(*args, **kwargs)
    except grpc.RpcError as e:
        raise ProximaError.from_rpc(e) from None


# A snapshot's camera: (eye, target, up or None, vertical fov in degrees).
_Camera = Optional[Tuple[ArrayLike, ArrayLike, Optional[ArrayLike], float]]


def _vec3(v: ArrayLike) -> Any:
    return pb.Vec3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _snapshot_request(width: int, height: int, camera: _Camera, collisions: bool,
                      tolerance: Optional[float], separation: bool, **target: Any) -> Any:
    """A SnapshotRequest for `target` (scene_id=..., or model=... and its region fields) with the
    image and colouring options both snapshot calls take."""
    request = pb.SnapshotRequest(width=width, height=height, collisions=collisions,
                                 separation=separation, **target)
    if tolerance is not None:
        request.tolerance = tolerance
    if camera is not None:
        eye, target_point, up, fov = camera
        request.camera.eye.CopyFrom(_vec3(eye))
        request.camera.target.CopyFrom(_vec3(target_point))
        if up is not None:
            request.camera.up.CopyFrom(_vec3(up))
        request.camera.fov_degrees = float(fov)
    return request


def read_token_file(path: Union[str, Path]) -> str:
    """The bearer token in a file: its first line, trimmed. Warns (on standard error) when every
    user can read the file; raises ProximaError naming the file when it cannot be read."""
    try:
        with open(path, encoding="utf-8") as f:
            line = f.readline().strip()
        mode = os.stat(path).st_mode
    except OSError as e:
        code = (grpc.StatusCode.NOT_FOUND if isinstance(e, FileNotFoundError)
                else grpc.StatusCode.FAILED_PRECONDITION)
        raise ProximaError(code, f"token file '{path}': {e.strerror}") from None
    if not line:
        raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT,
                           f"token file '{path}': the first line is empty")
    if mode & 0o004:
        print(f"proxima: warning: token file '{path}' is readable by every user "
              f"(mode {mode & 0o7777:04o}); the token is a password: chmod 600 it",
              file=sys.stderr)
    return line


def _read_pem(path: Optional[str], what: str, marker: bytes) -> Optional[bytes]:
    if not path:
        return None
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        code = (grpc.StatusCode.NOT_FOUND if isinstance(e, FileNotFoundError)
                else grpc.StatusCode.FAILED_PRECONDITION)
        raise ProximaError(code, f"{what} '{path}': {e.strerror}") from None
    if b"-----BEGIN " not in data or marker not in data:
        kind = "private key" if b"KEY" in marker else "certificate"
        raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT, f"{what} '{path}' holds no PEM {kind}")
    return data


class _Requests:
    """The request side of a streaming call: put() messages, end() half-closes."""

    def __init__(self) -> None:
        self._queue: "queue.Queue[Any]" = queue.Queue()
        self.closed = False

    def __iter__(self) -> Iterator[Any]:
        return iter(self._queue.get, _END)

    def put(self, message: Any) -> None:
        if self.closed:
            raise ProximaError(grpc.StatusCode.FAILED_PRECONDITION, "the stream is closed")
        self._queue.put(message)

    def end(self) -> None:
        if not self.closed:
            self.closed = True
            self._queue.put(_END)


class FrameStream:
    """One StreamFrames call in lockstep: send() a frame, receive() its Result. Up to the
    daemon's max_frames_in_flight frames may be sent before receiving. A context manager
    (close() on exit, cancel() when leaving with an exception)."""

    def __init__(self, stub: Any, metadata: Any, timeout: Optional[float] = None):
        self._requests = _Requests()
        self._responses = stub.StreamFrames(iter(self._requests), metadata=metadata,
                                            timeout=timeout)
        self._reported = False  # the stream's error was raised to the caller already

    def send(self, frame: Any) -> None:
        """Sends a Frame (make_frame); raises ProximaError after close() or cancel()."""
        self._requests.put(frame)

    def receive(self) -> Result:
        """The next frame's Result; raises ProximaError with the stream's status."""
        try:
            return Result(next(self._responses))
        except grpc.RpcError as e:
            self._reported = True
            raise ProximaError.from_rpc(e) from None
        except StopIteration:
            raise ProximaError(grpc.StatusCode.INTERNAL,
                               "the daemon ended the stream without a result") from None

    def query(self, frame: Any) -> Result:
        """send() then receive(): one frame in lockstep."""
        self.send(frame)
        return self.receive()

    def close(self) -> None:
        """Half-closes and drains: raises the stream's error if it ended with one not raised
        before."""
        self._requests.end()
        try:
            for _ in self._responses:
                pass
        except grpc.RpcError as e:
            if not self._reported:
                self._reported = True
                raise ProximaError.from_rpc(e) from None

    def cancel(self) -> None:
        """Cancels the call (the daemon sees CANCELLED; a stream-owned scene goes)."""
        self._requests.closed = True
        self._responses.cancel()
        self._requests.end()

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, kind: Any, *rest: Any) -> None:
        if kind is None:
            self.close()
        else:
            self.cancel()


class _ServerStream(Iterator[T]):
    """Iterates a server-streaming call, raising ProximaError; cancel() stops it."""

    def __init__(self, call: Any, wrap: Callable[[Any], T]):
        self._call = call
        self._wrap = wrap

    def __iter__(self) -> "_ServerStream[T]":
        return self

    def __next__(self) -> T:
        try:
            return self._wrap(next(self._call))
        except grpc.RpcError as e:
            raise ProximaError.from_rpc(e) from None

    def cancel(self) -> None:
        """Cancels the call; the next read raises ProximaError(CANCELLED)."""
        self._call.cancel()


class ResultStream(_ServerStream[Result]):
    """The Results of Client.stream(), one per frame, in order; cancel() stops the stream."""


class VerifyStream(_ServerStream[Any]):
    """The VerifyModelEvents of Client.verify_model() (each with one of `progress`, `pair`,
    `summary`: `event.WhichOneof("event")`); cancel() stops the traversal."""

    def result(self, on_progress: Optional[Callable[[Any], None]] = None) -> "VerifyResult":
        """Reads the whole stream: the pairs (sorted by object pair) and the summary.
        `on_progress` is called with each VerifyProgress."""
        out = VerifyResult()
        for event in self:
            kind = event.WhichOneof("event")
            if kind == "pair":
                out.pairs.append(event.pair)
            elif kind == "summary":
                out.summary = event.summary
            elif kind == "progress" and on_progress is not None:
                on_progress(event.progress)
        out.pairs.sort(key=lambda p: (p.object_a, p.object_b))
        return out


@dataclass
class VerifyResult:
    """A finished verification: `pairs` (ObjectPairResult messages, sorted by (object_a,
    object_b)) and `summary` (VerifyStats)."""

    pairs: List[Any] = field(default_factory=list)
    summary: Any = None

    @property
    def object_pairs(self) -> np.ndarray:
        """(K, 2) int64 (object_a, object_b) of each pair."""
        return np.array([(p.object_a, p.object_b) for p in self.pairs],
                        dtype=np.int64).reshape(-1, 2)

    @property
    def distances(self) -> np.ndarray:
        """(K,) the distance of each pair."""
        return np.array([p.distance for p in self.pairs], dtype=np.float64)

    @property
    def triangles(self) -> np.ndarray:
        """(K, 2) int64 (triangle_a, triangle_b): each pair's closest triangles."""
        return np.array([(p.triangle_a, p.triangle_b) for p in self.pairs],
                        dtype=np.int64).reshape(-1, 2)

    @property
    def points(self) -> np.ndarray:
        """(K, 2, 3): each pair's closest points (on object_a, on object_b)."""
        return np.array([((p.point_a.x, p.point_a.y, p.point_a.z),
                          (p.point_b.x, p.point_b.y, p.point_b.z)) for p in self.pairs],
                        dtype=np.float64).reshape(-1, 2, 3)


class RegionStream(_ServerStream[Any]):
    """The RegionEvents of Client.fetch_region() (each with one of `piece`, `progress`,
    `summary`: `event.WhichOneof("event")`), nearest piece first; cancel() stops the fetch."""

    def result(self, on_progress: Optional[Callable[[Any], None]] = None) -> "RegionResult":
        """Reads the whole stream: the pieces (RegionPiece messages, in the order sent) and the
        summary (RegionSummary). `on_progress` is called with each RegionProgress."""
        out = RegionResult()
        for event in self:
            kind = event.WhichOneof("event")
            if kind == "piece":
                out.pieces.append(event.piece)
            elif kind == "summary":
                out.summary = event.summary
            elif kind == "progress" and on_progress is not None:
                on_progress(event.progress)
        return out


@dataclass
class RegionResult:
    """A finished region fetch: `pieces` (RegionPiece messages, nearest first) and `summary`
    (RegionSummary)."""

    pieces: List[Any] = field(default_factory=list)
    summary: Any = None

    def meshes(self) -> List[Tuple[int, Mesh, np.ndarray]]:
        """Each piece as (object, Mesh in model coordinates, triangle_ids: (T,) uint32, each
        triangle's id in its whole object)."""
        return [(p.object, decode_mesh(p.mesh), np.array(p.triangle_ids, dtype=np.uint32))
                for p in self.pieces]


class ReviewSession:
    """One member's Review stream in a room. Joining sends `join` and waits for `joined` (the
    ReviewJoined message is `self.joined`). A thread reads the events as they come (the daemon
    disconnects members that fall 1024 events behind); next_event() takes them in order.

    pose() and the edit calls send a request and wait for its answer (the AvatarResult, or the
    EditApplied of this member's edit); events met meanwhile (peer updates, other members'
    edits, joins and leaves) stay queued for next_event(), a peer's update replaced by its newer
    one (as the daemon coalesces them). send_pose() and send_edit() only send.
    A context manager: close() on exit, cancel() when leaving with an exception."""

    def __init__(self, stub: Any, metadata: Any, room: str, model: str, member: str,
                 avatar: Mesh, tolerance: float, nearest: bool, timeout: Optional[float]):
        self.member = member
        self._requests = _Requests()
        self._events: "queue.Queue[Any]" = queue.Queue()
        self._held: List[Any] = []  # read while waiting for an answer, not yet taken
        self._sequence = 0
        self._timeout = timeout
        self._reported = False  # the stream's error was raised to the caller already
        self._requests.put(pb.ReviewRequest(join=pb.ReviewJoin(
            room=room, model=model, member=member, avatar=encode_mesh(avatar),
            tolerance=tolerance, nearest=nearest)))
        self._call = stub.Review(iter(self._requests), metadata=metadata)
        self._reader = threading.Thread(target=self._read, daemon=True,
                                        name=f"proxima-review-{member}")
        self._reader.start()
        try:
            first = self._take(timeout)
            if first.WhichOneof("event") != "joined":
                raise ProximaError(grpc.StatusCode.INTERNAL,
                                   f"the daemon answered join with {first.WhichOneof('event')}")
        except BaseException:
            self.cancel()
            raise
        self.joined: Any = first.joined

    def _read(self) -> None:
        try:
            for event in self._call:
                if event.WhichOneof("event") == "peers":
                    # Several peers' updates in one message: each is its own "peer" event.
                    for update in event.peers.updates:
                        self._events.put(pb.ReviewEvent(peer=update))
                else:
                    self._events.put(event)
            self._events.put(None)
        except grpc.RpcError as e:
            self._events.put(ProximaError.from_rpc(e))

    def _take(self, timeout: Optional[float]) -> Any:
        try:
            item = self._events.get(timeout=timeout)
        except queue.Empty:
            raise ProximaError(grpc.StatusCode.DEADLINE_EXCEEDED,
                               f"no review event within {timeout:g} s") from None
        if isinstance(item, ProximaError):
            self._events.put(item)  # every later read raises it too
            self._reported = True
            raise item
        if item is None:
            self._events.put(None)
            raise ProximaError(grpc.StatusCode.CANCELLED, "the review stream has ended")
        return item

    def next_event(self, timeout: Optional[float] = None, kind: Optional[str] = None) -> Any:
        """The next ReviewEvent (`event.WhichOneof("event")`: "result", "peer", "edit_applied",
        "member_joined", "member_left"), or with `kind` the next one of that kind (the others
        stay queued, in order). Raises ProximaError with the stream's status when it ended with
        an error, CANCELLED when it ended, DEADLINE_EXCEEDED after `timeout` s."""
        for i, event in enumerate(self._held):
            if kind is None or event.WhichOneof("event") == kind:
                return self._held.pop(i)
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            event = self._take(left)
            if kind is None or event.WhichOneof("event") == kind:
                return event
            self._hold(event)

    def _wait(self, match: Callable[[Any], bool]) -> Any:
        while True:
            event = self._take(self._timeout)
            if match(event):
                return event
            self._hold(event)

    def _hold(self, event: Any) -> None:
        # As the daemon's outbox does: a peer's update not yet taken is replaced by its newer
        # one, moved to the end; so a member that only poses holds one update per peer, not
        # every pose the room published.
        if event.WhichOneof("event") == "peer":
            self._held = [e for e in self._held if e.WhichOneof("event") != "peer"
                          or e.peer.member != event.peer.member]
        self._held.append(event)

    def send_pose(self, pose: ArrayLike, sequence: Optional[int] = None) -> int:
        """Sends a pose (see geometry.transform: a (3, 4) matrix, 12 numbers or a translation)
        and returns its sequence number (by default one more than the last)."""
        self._sequence = self._sequence + 1 if sequence is None else sequence
        self._requests.put(pb.ReviewRequest(pose=pb.ReviewPose(sequence=self._sequence,
                                                               transform=transform(pose))))
        return self._sequence

    def pose(self, pose: ArrayLike) -> Any:
        """Sends a pose and returns its AvatarResult (`collisions`, `within`, `nearest`, ...)."""
        sequence = self.send_pose(pose)
        return self._wait(lambda e: e.WhichOneof("event") == "result" and
                          e.result.sequence == sequence).result

    def send_edit(self, move: Optional[Tuple[int, ArrayLike]] = None, add: Optional[Mesh] = None,
                  remove: Optional[int] = None) -> int:
        """Sends one edit (exactly one of: move=(object, transform), add=Mesh, remove=object)
        and returns its sequence number."""
        if sum(x is not None for x in (move, add, remove)) != 1:
            raise ValueError("an edit is exactly one of move, add, remove")
        self._sequence += 1
        edit = pb.ReviewEdit(sequence=self._sequence)
        if move is not None:
            edit.move.object = int(move[0])
            edit.move.transform.CopyFrom(transform(move[1]))
        elif add is not None:
            edit.add.CopyFrom(encode_mesh(add))
        else:
            edit.remove.object = int(remove)  # type: ignore[arg-type]
        self._requests.put(pb.ReviewRequest(edit=edit))
        return self._sequence

    def _edit(self, **kwargs: Any) -> Any:
        sequence = self.send_edit(**kwargs)
        return self._wait(lambda e: e.WhichOneof("event") == "edit_applied" and
                          e.edit_applied.member == self.member and
                          e.edit_applied.sequence == sequence).edit_applied

    def move(self, obj: int, matrix: ArrayLike) -> Any:
        """Moves stored object `obj` (its stored coordinates by `matrix`); the EditApplied."""
        return self._edit(move=(obj, matrix))

    def add(self, mesh: Mesh) -> Any:
        """Adds an object; the EditApplied (`object` is its new index)."""
        return self._edit(add=mesh)

    def remove(self, obj: int) -> Any:
        """Deletes object `obj`; the EditApplied."""
        return self._edit(remove=obj)

    def close(self) -> None:
        """Half-closes (the member leaves the room) and waits for the stream's end; raises its
        error if it ended with one not raised before."""
        self._requests.end()
        self._reader.join(self._timeout)
        while not self._events.empty():
            item = self._events.get()
            if isinstance(item, ProximaError) and not self._reported:
                self._reported = True
                raise item

    def cancel(self) -> None:
        """Cancels the call (the member leaves the room)."""
        self._requests.closed = True
        self._call.cancel()
        self._requests.end()

    def __enter__(self) -> "ReviewSession":
        return self

    def __exit__(self, kind: Any, *rest: Any) -> None:
        if kind is None:
            self.close()
        else:
            self.cancel()


# The metadata key of Client's `route` (a load balancer's consistent-hash key).
ROUTE_HEADER = "x-proxima-route"


class Client:
    """A connection to proximad (a context manager).

    - `connect_timeout`: seconds to wait for the channel (ProximaError UNAVAILABLE after)
    - `timeout`: the deadline of each unary call in seconds (None: none)
    - `float32`: send every vertex array as float32 (False: each array's own dtype, so float32
      arrays still travel as float32 and everything else as float64)
    - `inline_mesh_bytes`: create_scene sends objects inline up to this many bytes in all,
      uploads the rest
    - `token` / `token_file`: every call carries `authorization: Bearer <token>`
    - `tls_ca` (PEM root CA file; None: the system's roots), `tls_cert` and `tls_key` (this
      client's PEM certificate and key, mutual TLS), `tls_server_name` (the name the daemon's
      certificate must hold instead of the host): any of them makes the channel TLS
    - `route`: the routing key for a load balancer in front of several daemons
      (docs/deploy.md): every call carries `x-proxima-route: <route>`, so every call of one
      scene reaches one daemon; choose it before creating the scene (its name, say) and use
      one Client per route. None: a random key of this Client's own (`client-` and 16 hex
      digits), and a review stream carries its room's name instead. The daemon ignores it.
    """

    def __init__(self, address: str, connect_timeout: float = 5.0,
                 timeout: Optional[float] = None, float32: bool = False,
                 inline_mesh_bytes: int = 1 << 20, token: Optional[str] = None,
                 token_file: Optional[Union[str, Path]] = None, tls_ca: Optional[str] = None,
                 tls_cert: Optional[str] = None, tls_key: Optional[str] = None,
                 tls_server_name: Optional[str] = None, route: Optional[str] = None):
        # Results of big scenes outgrow gRPC's 4 MiB default; the daemon's limits apply anyway.
        options: List[Tuple[str, Any]] = [("grpc.max_receive_message_length", -1),
                                          ("grpc.max_send_message_length", -1)]
        if token_file is not None:
            if token is not None:
                raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT,
                                   "give token or token_file, not both")
            token = read_token_file(token_file)
        if token is not None and (not token or any(not 0x20 <= ord(c) <= 0x7e for c in token)):
            raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT,
                               "the token must be non-empty printable ASCII")
        if route is not None and (not route or any(not 0x20 <= ord(c) <= 0x7e for c in route)):
            raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT,
                               "the route must be non-empty printable ASCII")
        self._explicit_route = route is not None
        self.route = route if route is not None else f"client-{os.urandom(8).hex()}"
        self._auth: Tuple[Tuple[str, str], ...] = (
            (("authorization", f"Bearer {token}"),) if token else ())
        self._metadata = self._auth + ((ROUTE_HEADER, self.route),)
        tls = bool(tls_ca or tls_cert or tls_key or tls_server_name)
        if tls:
            if bool(tls_cert) != bool(tls_key):
                raise ProximaError(grpc.StatusCode.INVALID_ARGUMENT,
                                   "mutual TLS needs both tls_cert and tls_key")
            credentials = grpc.ssl_channel_credentials(
                root_certificates=_read_pem(tls_ca, "TLS root CA file", b"CERTIFICATE-----"),
                private_key=_read_pem(tls_key, "TLS client key file", b"PRIVATE KEY-----"),
                certificate_chain=_read_pem(tls_cert, "TLS client certificate file",
                                            b"CERTIFICATE-----"))
            if tls_server_name:
                options.append(("grpc.ssl_target_name_override", tls_server_name))
            self._channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        try:
            grpc.channel_ready_future(self._channel).result(timeout=connect_timeout)
        except grpc.FutureTimeoutError:
            self._channel.close()
            raise ProximaError(grpc.StatusCode.UNAVAILABLE,
                               f"cannot reach proximad at {address} within "
                               f"{connect_timeout:g} s" + (" (over TLS)" if tls else "")) from None
        self.address = address
        self.stub = pb_grpc.ProximityStub(self._channel)
        self.timeout = timeout
        self.float32 = float32
        self.inline_mesh_bytes = inline_mesh_bytes

    def _unary(self, method: Callable[..., T], request: Any, room: str = "") -> T:
        return _call(method, request, timeout=self.timeout, metadata=self._room_metadata(room))

    def _room_metadata(self, room: str) -> Tuple[Tuple[str, str], ...]:
        """The call metadata; a room's view lives on the daemon its members meet on, so a call
        about `room` is routed by the room's name, unless this Client was given a route."""
        if self._explicit_route or not room:
            return self._metadata
        return self._auth + ((ROUTE_HEADER, room),)

    def _float32(self) -> Optional[bool]:
        return True if self.float32 else None

    def close(self) -> None:
        """Closes the channel (calls in progress are cancelled)."""
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # --- scenes ---------------------------------------------------------------------------

    def server_info(self) -> Any:
        """GetServerInfo: version, api ("proxima.v1"), limits, backends, principal, quotas."""
        return self._unary(self.stub.GetServerInfo, pb.GetServerInfoRequest())

    def create_scene(self, meshes: Sequence[Mesh] = (), name: str = "") -> Any:
        """CreateScene with these objects in this order (their result order); the SceneInfo
        (`scene_id`, `objects[i].id`). Objects travel inline while their total stays within
        inline_mesh_bytes; the rest are uploaded in order (uploads append). A failed upload
        deletes the scene again."""
        request = pb.CreateSceneRequest(name=name)
        used, k = 0, len(meshes)
        for i, mesh in enumerate(meshes):
            encoded = encode_mesh(mesh, self._float32())
            used += encoded.ByteSize()
            if used > self.inline_mesh_bytes:
                k = i
                break
            request.objects.append(encoded)
        scene = self._unary(self.stub.CreateScene, request)
        try:
            for mesh in meshes[k:]:
                obj = self.upload_object(scene.scene_id, mesh)
                scene.objects.append(obj)
                scene.triangle_count += obj.triangle_count
        except BaseException:
            try:
                self.delete_scene(scene.scene_id)
            except ProximaError:
                pass
            raise
        return scene

    def describe_scene(self, scene_id: str) -> Any:
        """DescribeScene: the SceneInfo (objects in result order, frames applied)."""
        return self._unary(self.stub.DescribeScene, pb.DescribeSceneRequest(scene_id=scene_id))

    def delete_scene(self, scene_id: str) -> None:
        """DeleteScene."""
        self._unary(self.stub.DeleteScene, pb.DeleteSceneRequest(scene_id=scene_id))

    def upload_object(self, scene_id: str, mesh: Mesh,
                      chunk_bytes: int = UPLOAD_CHUNK_BYTES) -> Any:
        """UploadObject: adds one object of any size in chunks of at most `chunk_bytes`; the
        ObjectInfo (its `id`)."""
        vertices = pack_vertices(mesh.vertices, self._float32())
        indices = pack_triangles(mesh.triangles)

        def chunks() -> Iterator[Any]:
            yield pb.UploadChunk(header=pb.UploadHeader(
                scene_id=scene_id, name=mesh.name, type=vertices.type,
                vertex_count=len(mesh.vertices), triangle_count=len(mesh.triangles)))
            for i in range(0, len(vertices.data), chunk_bytes):
                yield pb.UploadChunk(vertex_bytes=vertices.data[i:i + chunk_bytes])
            for i in range(0, len(indices), chunk_bytes):
                yield pb.UploadChunk(index_bytes=indices[i:i + chunk_bytes])

        return self._unary(self.stub.UploadObject, chunks())

    def snapshot(self, scene_id: str, width: int = 800, height: int = 600,
                 camera: _Camera = None, collisions: bool = True,
                 tolerance: Optional[float] = None, separation: bool = True) -> Any:
        """Snapshot: an offscreen PNG of the scene, results coloured (collisions red, pairs within
        `tolerance` amber, closest pairs as segments). `camera`: (eye, target, up or None, vertical
        fov in degrees); None fits the scene. The SnapshotResponse (`png` bytes, `camera` used,
        `width`, `height`, `gl_renderer`, `collision_count`, `tolerance_count`,
        `segment_count`)."""
        request = _snapshot_request(width, height, camera, collisions, tolerance, separation,
                                    scene_id=scene_id)
        return self._unary(self.stub.Snapshot, request)

    def snapshot_region(self, model: str, center: ArrayLike = (0.0, 0.0, 0.0),
                        radius: float = 0.0, room: str = "", max_triangles: int = 0,
                        width: int = 800, height: int = 600, camera: _Camera = None,
                        collisions: bool = True, tolerance: Optional[float] = None,
                        separation: bool = True) -> Any:
        """Snapshot of a served massive model's region (the pieces FetchRegion selects for
        `center`, `radius`, `room`, `max_triangles`), coloured as snapshot() colours a scene.
        The SnapshotResponse, its `region` holding the pieces, triangles and objects drawn."""
        request = _snapshot_request(width, height, camera, collisions, tolerance, separation,
                                    model=model, center=_vec3(center), radius=float(radius),
                                    room=room, max_triangles=max_triangles)
        return self._unary(self.stub.Snapshot, request, room=room)

    # --- frames ---------------------------------------------------------------------------

    def query(self, scene_id: str, **frame_args: Any) -> Result:
        """One frame on an existing scene (the Query RPC); keywords as for make_frame."""
        frame_args.setdefault("float32", self._float32())
        return Result(self._unary(self.stub.Query, make_frame(scene_id=scene_id, **frame_args)))

    def stream(self, frames: Iterable[Any], timeout: Optional[float] = None) -> ResultStream:
        """StreamFrames: sends the Frames of `frames` (make_frame) and yields one Result per
        frame, in order. gRPC pulls from `frames` as flow control allows (pipelined), so a
        generator may also wait for the previous result before producing the next frame. With
        an empty scene_id on the first frame the scene is created from its additions and
        deleted when the stream ends. cancel() on the returned stream stops it."""
        return ResultStream(self.stub.StreamFrames(iter(frames), metadata=self._metadata,
                                                   timeout=timeout), Result)

    def open_stream(self, timeout: Optional[float] = None) -> FrameStream:
        """A StreamFrames call for lockstep use: send(frame), receive(), close(), cancel()."""
        return FrameStream(self.stub, self._metadata, timeout)

    # --- massive models -------------------------------------------------------------------

    def list_models(self) -> Any:
        """ListModels: `models` (ModelInfo by name), `unavailable`, `models_dir`, `cache`."""
        return self._unary(self.stub.ListModels, pb.ListModelsRequest())

    def verify_model(self, model: str, tolerance: float = 0.0,
                     timeout: Optional[float] = None) -> VerifyStream:
        """VerifyModel: the stream of events (progress, pair, summary last); iterate it, or
        take .result(). cancel() stops the traversal."""
        return VerifyStream(self.stub.VerifyModel(
            pb.VerifyModelRequest(model=model, tolerance=tolerance), metadata=self._metadata,
            timeout=timeout), lambda e: e)

    def verify(self, model: str, tolerance: float = 0.0,
               on_progress: Optional[Callable[[Any], None]] = None,
               timeout: Optional[float] = None) -> VerifyResult:
        """Every object pair of `model` within `tolerance` (0: touching or intersecting): the
        VerifyResult (pairs sorted by object pair, the summary)."""
        return self.verify_model(model, tolerance, timeout).result(on_progress)

    def fetch_region(self, model: str, center: ArrayLike = (0.0, 0.0, 0.0), radius: float = 0.0,
                     room: str = "", objects: Sequence[int] = (), max_triangles: int = 0,
                     float64: bool = False, timeout: Optional[float] = None) -> RegionStream:
        """FetchRegion: the pieces of `model` whose boxes come within `radius` of `center`
        (radius 0: every piece), nearest first, then the summary; with `room`, that review
        room's edited view. Iterate the stream, or take .result(); cancel() stops it."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        request = pb.FetchRegionRequest(
            model=model, center=pb.Vec3(x=float(c[0]), y=float(c[1]), z=float(c[2])),
            radius=radius, room=room, objects=list(objects), max_triangles=max_triangles,
            type=pb.SCALAR_TYPE_FLOAT64 if float64 else pb.SCALAR_TYPE_FLOAT32)
        return RegionStream(self.stub.FetchRegion(request, metadata=self._room_metadata(room),
                                                  timeout=timeout),
                            lambda e: e)

    def review(self, room: str, model: str, member: str, avatar: Mesh, tolerance: float = 0.0,
               nearest: bool = True, timeout: Optional[float] = 60.0) -> ReviewSession:
        """Joins review room `room` on `model` as `member` with `avatar` (in its own
        coordinates; poses place it). The ReviewSession; `timeout` bounds each wait for an
        answer (None: none)."""
        # A room's members must meet on one daemon: the room's name is their route.
        return ReviewSession(self.stub, self._room_metadata(room), room, model, member, avatar, tolerance,
                             nearest, timeout)
