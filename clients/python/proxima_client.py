"""A small Python client for proximad (API proxima.v1).

Needs Debian's python3-grpcio and python3-protobuf (for /usr/bin/python3), protoc and
/usr/bin/grpc_python_plugin: the Python stubs are generated from proto/proxima/v1/proxima.proto
into a temporary folder when this module is imported, so no generated code is committed and the
stubs always match the proto in this tree. Geometry is packed with `array` (little-endian, no
numpy). Results are the proto's FrameResult messages; the proto's comments document every field.

    from proxima_client import Client, box
    with Client("127.0.0.1:50051") as client:
        scene = client.create_scene([box("a", (0, 0, 0), (1, 1, 1)),
                                     box("b", (1.5, 0, 0), (2.5, 1, 1))])
        result = client.query(scene.scene_id)
        print(result.separation[0].distance)  # 0.5
        client.delete_scene(scene.scene_id)

Errors from the daemon raise ProximaError, whose `code` is the gRPC status name
("INVALID_ARGUMENT", "NOT_FOUND", ...) and whose `message` is the daemon's message.
"""
import array
import atexit
import importlib
import os
import queue
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import grpc

_REPO = Path(__file__).resolve().parents[2]
PROTO = _REPO / "proto" / "proxima" / "v1" / "proxima.proto"
PROTOC = os.environ.get("PROXIMA_PROTOC", "protoc")
GRPC_PYTHON_PLUGIN = os.environ.get("PROXIMA_GRPC_PYTHON_PLUGIN", "/usr/bin/grpc_python_plugin")


def _generate_stubs():
    """Runs protoc on the tree's proto and imports the result (proxima_pb2, proxima_pb2_grpc).

    The proto is compiled from its own folder so the modules are top-level (`proxima_pb2`) and
    cannot collide with any `proxima` package on sys.path; the API package stays `proxima.v1`.
    """
    out = tempfile.mkdtemp(prefix="proxima-pb-")
    atexit.register(shutil.rmtree, out, True)
    cmd = [PROTOC, f"--proto_path={PROTO.parent}", f"--python_out={out}",
           f"--grpc_python_out={out}", f"--plugin=protoc-gen-grpc_python={GRPC_PYTHON_PLUGIN}",
           str(PROTO)]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True)
    except FileNotFoundError as e:
        raise RuntimeError(f"cannot run {PROTOC} (Debian package protobuf-compiler): {e}") from e
    if p.returncode != 0:
        raise RuntimeError(f"generating the Python stubs failed: {' '.join(cmd)}\n{p.stderr}")
    sys.path.insert(0, out)
    try:
        return (importlib.import_module("proxima_pb2"),
                importlib.import_module("proxima_pb2_grpc"))
    finally:
        sys.path.remove(out)


pb, pb_grpc = _generate_stubs()


class ProximaError(Exception):
    """A failed call: `code` is the gRPC status name, `message` the daemon's message."""

    def __init__(self, code: str, message: str):
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message

    @staticmethod
    def from_rpc(error: grpc.RpcError) -> "ProximaError":
        code = error.code() if hasattr(error, "code") else None
        details = error.details() if hasattr(error, "details") else str(error)
        return ProximaError(code.name if code is not None else "UNKNOWN", details or "")


def _call(fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except grpc.RpcError as e:
        raise ProximaError.from_rpc(e) from None


# --- geometry --------------------------------------------------------------------------------

Vec3 = Tuple[float, float, float]


@dataclass
class Mesh:
    """An indexed triangle mesh: vertices (x, y, z) and triangles (three vertex indices)."""
    name: str
    vertices: Sequence[Vec3]
    triangles: Sequence[Tuple[int, int, int]]


def box(name: str, lo: Vec3, hi: Vec3) -> Mesh:
    """Axis-aligned box [lo, hi] as 12 outward-facing triangles."""
    v = [(hi[0] if k & 1 else lo[0], hi[1] if k & 2 else lo[1], hi[2] if k & 4 else lo[2])
         for k in range(8)]
    f = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
         (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)]
    return Mesh(name, v, f)


def _little_endian(a: array.array) -> bytes:
    if sys.byteorder != "little":
        a.byteswap()
    return a.tobytes()


def _uint32_array() -> array.array:
    # 'I' is 4 bytes on every platform Debian ships; 'L' is the fallback where it is not.
    return array.array("I" if array.array("I").itemsize == 4 else "L")


def pack_vertices(vertices: Sequence[Vec3], float32: bool = False) -> "pb.VertexBuffer":
    """Packed little-endian x, y, z per vertex, float64 (exact) or float32."""
    a = array.array("f" if float32 else "d", (c for v in vertices for c in v))
    return pb.VertexBuffer(type=pb.SCALAR_TYPE_FLOAT32 if float32 else pb.SCALAR_TYPE_FLOAT64,
                           data=_little_endian(a))


def pack_triangles(triangles: Sequence[Tuple[int, int, int]]) -> bytes:
    """Packed little-endian uint32, three per triangle."""
    a = _uint32_array()
    a.extend(i for t in triangles for i in t)
    return _little_endian(a)


def unpack_vertices(buffer: "pb.VertexBuffer") -> List[Vec3]:
    a = array.array("f" if buffer.type == pb.SCALAR_TYPE_FLOAT32 else "d")
    if buffer.type not in (pb.SCALAR_TYPE_FLOAT32, pb.SCALAR_TYPE_FLOAT64) or \
            len(buffer.data) % (3 * a.itemsize):
        raise ValueError(f"malformed vertex buffer: type {buffer.type}, {len(buffer.data)} bytes")
    a.frombytes(buffer.data)
    if sys.byteorder != "little":
        a.byteswap()
    return [(a[i], a[i + 1], a[i + 2]) for i in range(0, len(a), 3)]


def encode_mesh(mesh: Mesh, float32: bool = False) -> "pb.Mesh":
    return pb.Mesh(name=mesh.name, vertices=pack_vertices(mesh.vertices, float32),
                   indices=pack_triangles(mesh.triangles))


_CULLERS = {"auto": pb.CULLER_AUTO, "brute": pb.CULLER_BRUTE, "bvh": pb.CULLER_BVH}


def make_frame(scene_id: str = "", frame: int = 0,
               positions: Optional[Dict[int, Sequence[Vec3]]] = None,
               topology_changes: Optional[Dict[int, Sequence[Mesh]]] = None,
               additions: Sequence[Mesh] = (), removals: Sequence[int] = (),
               separation: bool = True, self_query: bool = False, collisions: bool = False,
               tolerance: Optional[float] = None, pns: bool = False, culler: str = "auto",
               self_points: bool = False, float32: bool = False) -> "pb.Frame":
    """One Frame: changes by daemon object id (new positions, objects replaced by fragments,
    additions, removals) and the queries to run on the result."""
    f = pb.Frame(scene_id=scene_id, frame=frame, removals=list(removals))
    for object_id, vertices in (positions or {}).items():
        f.positions.add(object_id=object_id, vertices=pack_vertices(vertices, float32))
    for object_id, fragments in (topology_changes or {}).items():
        f.topology_changes.add(object_id=object_id,
                               fragments=[encode_mesh(m, float32) for m in fragments])
    f.additions.extend(encode_mesh(m, float32) for m in additions)
    q = f.queries
    q.separation, q.self, q.collisions, q.pns = separation, self_query, collisions, pns
    q.culler = _CULLERS[culler]
    q.self_points = self_points
    if tolerance is not None:
        q.tolerance = tolerance
    return f


# --- the client ------------------------------------------------------------------------------

UPLOAD_CHUNK_BYTES = 1 << 20


class FrameStream:
    """One StreamFrames call used in lockstep: send() a frame, receive() its FrameResult. Up to
    the daemon's max_frames_in_flight frames may be sent before receiving."""

    def __init__(self, stub, metadata=None):
        self._requests: "queue.Queue" = queue.Queue()
        self._responses = stub.StreamFrames(iter(self._requests.get, None), metadata=metadata)
        self._closed = False

    def send(self, frame: "pb.Frame") -> None:
        if self._closed:
            raise ProximaError("FAILED_PRECONDITION", "send() after close()")
        self._requests.put(frame)

    def receive(self) -> "pb.FrameResult":
        try:
            return next(self._responses)
        except grpc.RpcError as e:
            raise ProximaError.from_rpc(e) from None
        except StopIteration:
            raise ProximaError("INTERNAL", "the daemon ended the stream without a result") from None

    def close(self) -> None:
        """Half-closes and drains: raises the stream's error if it ended with one."""
        if not self._closed:
            self._closed = True
            self._requests.put(None)
        try:
            for _ in self._responses:
                pass
        except grpc.RpcError as e:
            raise ProximaError.from_rpc(e) from None

    def cancel(self) -> None:
        self._closed = True
        self._responses.cancel()
        self._requests.put(None)


def read_token_file(path: str) -> str:
    """The bearer token in a file: its first line, trimmed. Warns (on standard error) when the
    file is readable by every user; raises ProximaError naming the file otherwise."""
    try:
        with open(path, encoding="utf-8") as f:
            line = f.readline().strip()
        mode = os.stat(path).st_mode
    except OSError as e:
        raise ProximaError("NOT_FOUND" if isinstance(e, FileNotFoundError) else
                           "FAILED_PRECONDITION", f"token file '{path}': {e.strerror}") from None
    if not line:
        raise ProximaError("INVALID_ARGUMENT", f"token file '{path}': the first line is empty")
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
        raise ProximaError("NOT_FOUND" if isinstance(e, FileNotFoundError) else
                           "FAILED_PRECONDITION", f"{what} '{path}': {e.strerror}") from None
    if b"-----BEGIN " not in data or marker not in data:
        raise ProximaError("INVALID_ARGUMENT", f"{what} '{path}' holds no PEM "
                           f"{'private key' if b'KEY' in marker else 'certificate'}")
    return data


class Client:
    """A connection to proximad. `timeout` is the deadline of each unary call (None: none).

    `token`: every call carries `authorization: Bearer <token>`. TLS when any tls_* argument is
    given: `tls_ca` (PEM root CA file the daemon's certificate must chain to; None: the system's
    roots), `tls_cert` and `tls_key` (this client's PEM certificate and key, for mutual TLS),
    `tls_server_name` (the name the daemon's certificate must hold instead of the host)."""

    def __init__(self, address: str, connect_timeout: float = 5.0,
                 timeout: Optional[float] = None, float32: bool = False,
                 inline_mesh_bytes: int = 1 << 20, token: Optional[str] = None,
                 tls_ca: Optional[str] = None, tls_cert: Optional[str] = None,
                 tls_key: Optional[str] = None, tls_server_name: Optional[str] = None):
        # Results of big scenes outgrow gRPC's 4 MiB default; the daemon's limits apply anyway.
        options = [("grpc.max_receive_message_length", -1),
                   ("grpc.max_send_message_length", -1)]
        if token is not None and (not token or any(not 0x20 <= ord(c) <= 0x7e for c in token)):
            raise ProximaError("INVALID_ARGUMENT", "the token must be non-empty printable ASCII")
        self._metadata = (("authorization", f"Bearer {token}"),) if token else None
        tls = tls_ca or tls_cert or tls_key or tls_server_name
        if tls:
            if bool(tls_cert) != bool(tls_key):
                raise ProximaError("INVALID_ARGUMENT", "mutual TLS needs both tls_cert and tls_key")
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
            raise ProximaError("UNAVAILABLE", f"cannot reach proximad at {address} within "
                                              f"{connect_timeout:g} s" +
                               (" (over TLS)" if tls else "")) from None
        self._stub = pb_grpc.ProximityStub(self._channel)
        self.timeout = timeout
        self.float32 = float32
        self.inline_mesh_bytes = inline_mesh_bytes

    def _unary(self, method, request):
        """One call with this client's deadline and token."""
        return _call(method, request, timeout=self.timeout, metadata=self._metadata)

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def server_info(self) -> "pb.ServerInfo":
        return self._unary(self._stub.GetServerInfo, pb.GetServerInfoRequest())

    def create_scene(self, meshes: Sequence[Mesh], name: str = "") -> "pb.SceneInfo":
        """Creates a scene with these objects, in this order (their result order). Objects travel
        inline while their total stays within inline_mesh_bytes; the rest are uploaded in
        chunks, in order, since uploads append."""
        request = pb.CreateSceneRequest(name=name)
        used, k = 0, 0
        for k, mesh in enumerate(meshes):
            encoded = encode_mesh(mesh, self.float32)
            used += encoded.ByteSize()
            if used > self.inline_mesh_bytes:
                break
            request.objects.append(encoded)
        else:
            k = len(meshes)
        scene = self._unary(self._stub.CreateScene, request)
        try:
            for mesh in meshes[k:]:
                obj = self.upload_object(scene.scene_id, mesh)
                scene.objects.append(obj)
                scene.triangle_count += obj.triangle_count
        except ProximaError:
            self.delete_scene(scene.scene_id)
            raise
        return scene

    def describe_scene(self, scene_id: str) -> "pb.SceneInfo":
        return self._unary(self._stub.DescribeScene, pb.DescribeSceneRequest(scene_id=scene_id))

    def delete_scene(self, scene_id: str) -> None:
        self._unary(self._stub.DeleteScene, pb.DeleteSceneRequest(scene_id=scene_id))

    def upload_object(self, scene_id: str, mesh: Mesh) -> "pb.ObjectInfo":
        """Adds one object through UploadObject: a header, then chunks of at most 1 MiB."""
        vertices = pack_vertices(mesh.vertices, self.float32)
        indices = pack_triangles(mesh.triangles)

        def chunks():
            yield pb.UploadChunk(header=pb.UploadHeader(
                scene_id=scene_id, name=mesh.name, type=vertices.type,
                vertex_count=len(mesh.vertices), triangle_count=len(mesh.triangles)))
            for i in range(0, len(vertices.data), UPLOAD_CHUNK_BYTES):
                yield pb.UploadChunk(vertex_bytes=vertices.data[i:i + UPLOAD_CHUNK_BYTES])
            for i in range(0, len(indices), UPLOAD_CHUNK_BYTES):
                yield pb.UploadChunk(index_bytes=indices[i:i + UPLOAD_CHUNK_BYTES])

        return self._unary(self._stub.UploadObject, chunks())

    def query(self, scene_id: str, **frame_args) -> "pb.FrameResult":
        """One frame on an existing scene (the Query RPC); keywords as for make_frame."""
        frame_args.setdefault("float32", self.float32)
        return self._unary(self._stub.Query, make_frame(scene_id=scene_id, **frame_args))

    def stream(self, frames: Iterable["pb.Frame"]) -> Iterator["pb.FrameResult"]:
        """Streams frames (built with make_frame) and yields one FrameResult per frame, in order.
        gRPC pulls from `frames` as flow control allows, so a generator may wait for the previous
        result before producing the next frame. With an empty scene_id on the first frame the
        scene is created from its additions and deleted when the stream ends."""
        try:
            yield from self._stub.StreamFrames(iter(frames), metadata=self._metadata)
        except grpc.RpcError as e:
            raise ProximaError.from_rpc(e) from None

    def open_stream(self) -> FrameStream:
        """A stream for lockstep use (send, receive), like the C++ FrameStream."""
        return FrameStream(self._stub, self._metadata)
