"""Meshes as numpy arrays, and the proto's packed little-endian buffers.

Vertices are (N, 3) arrays of float64 (exact on the wire) or float32 (half the bytes; the daemon
computes in float64 either way); triangles are (M, 3) integer arrays of vertex indices, sent as
uint32. Anything array-like (lists of tuples) is accepted and converted.
"""
from dataclasses import dataclass
from typing import Any, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

from ._pb import proxima_pb2 as pb

ArrayLike = Union[npt.ArrayLike, Sequence[Sequence[float]]]

_F64 = np.dtype("<f8")
_F32 = np.dtype("<f4")
_U32 = np.dtype("<u4")


def as_vertices(vertices: ArrayLike, float32: Optional[bool] = None) -> np.ndarray:
    """`vertices` as an (N, 3) float array: float32 when `float32` is True or (None) when the
    input already is float32, float64 otherwise. Raises ValueError on another shape."""
    a = np.asarray(vertices)
    if a.size == 0:
        a = a.reshape(0, 3)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"vertices must be an (N, 3) array, got shape {a.shape}")
    if a.dtype.kind not in "fiu":
        raise ValueError(f"vertices must be numbers, got dtype {a.dtype}")
    single = float32 if float32 is not None else a.dtype == np.float32
    return np.ascontiguousarray(a, dtype=np.float32 if single else np.float64)


def as_triangles(triangles: ArrayLike) -> np.ndarray:
    """`triangles` as an (M, 3) uint32 array. Raises ValueError on another shape, non-integer
    values or indices outside [0, 2^32) (the daemon checks them against the vertex count)."""
    a = np.asarray(triangles)
    if a.size == 0:
        return np.zeros((0, 3), dtype=np.uint32)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"triangles must be an (M, 3) array, got shape {a.shape}")
    if a.dtype.kind not in "iu":
        raise ValueError(f"triangles must be integers, got dtype {a.dtype}")
    if a.min() < 0 or a.max() > 0xFFFFFFFF:
        raise ValueError("triangle indices must be in [0, 2^32)")
    return np.ascontiguousarray(a, dtype=np.uint32)


@dataclass(init=False, eq=False)  # numpy arrays have no single truth value
class Mesh:
    """An indexed triangle mesh: `name`, `vertices` (N, 3) float64 or float32, `triangles`
    (M, 3) uint32."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray

    def __init__(self, name: str, vertices: ArrayLike, triangles: ArrayLike,
                 float32: Optional[bool] = None):
        self.name = name
        self.vertices = as_vertices(vertices, float32)
        self.triangles = as_triangles(triangles)

    def translated(self, offset: ArrayLike, name: Optional[str] = None) -> "Mesh":
        """A copy moved by `offset` (3 numbers), same dtype and triangles."""
        moved = self.vertices + np.asarray(offset, dtype=self.vertices.dtype).reshape(1, 3)
        return Mesh(self.name if name is None else name, moved, self.triangles,
                    float32=self.vertices.dtype == np.float32)


def box(name: str, lo: ArrayLike, hi: ArrayLike, float32: bool = False) -> Mesh:
    """The axis-aligned box [lo, hi] as 8 vertices and 12 outward-facing triangles."""
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v = [(hi_[0] if k & 1 else lo_[0], hi_[1] if k & 2 else lo_[1], hi_[2] if k & 4 else lo_[2])
         for k in range(8)]
    f = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
         (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)]
    return Mesh(name, v, f, float32=float32)


def grid(name: str, n: int, origin: ArrayLike = (0.0, 0.0, 0.0), size: float = 1.0,
         float32: bool = False) -> Mesh:
    """A flat n x n grid of squares in the z = origin[2] plane: (n+1)^2 vertices, 2 n^2
    triangles. Handy for large meshes (uploads) and tests."""
    o = np.asarray(origin, dtype=np.float64)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    v = np.stack([o[0] + size * i.ravel() / n, o[1] + size * j.ravel() / n,
                  np.full((n + 1) ** 2, o[2])], axis=1)
    a = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + n + 2], axis=1),
                        np.stack([a, a + n + 2, a + n + 1], axis=1)])
    return Mesh(name, v, f, float32=float32)


def pack_vertices(vertices: ArrayLike, float32: Optional[bool] = None) -> Any:
    """A VertexBuffer: packed little-endian x, y, z per vertex (float32 as for as_vertices)."""
    a = as_vertices(vertices, float32)
    single = a.dtype == np.float32
    return pb.VertexBuffer(type=pb.SCALAR_TYPE_FLOAT32 if single else pb.SCALAR_TYPE_FLOAT64,
                           data=a.astype(_F32 if single else _F64, copy=False).tobytes())


def pack_triangles(triangles: ArrayLike) -> bytes:
    """Packed little-endian uint32, three per triangle."""
    return as_triangles(triangles).astype(_U32, copy=False).tobytes()


def unpack_vertices(buffer: Any) -> np.ndarray:
    """A VertexBuffer as an (N, 3) array of its own scalar type (float32 or float64)."""
    if buffer.type == pb.SCALAR_TYPE_FLOAT32:
        dtype = _F32
    elif buffer.type == pb.SCALAR_TYPE_FLOAT64:
        dtype = _F64
    else:
        raise ValueError(f"malformed vertex buffer: scalar type {buffer.type}")
    if len(buffer.data) % (3 * dtype.itemsize):
        raise ValueError(f"malformed vertex buffer: {len(buffer.data)} bytes")
    return np.frombuffer(buffer.data, dtype=dtype).astype(dtype.newbyteorder("="))\
        .reshape(-1, 3)


def unpack_triangles(data: bytes) -> np.ndarray:
    """Packed indices as an (M, 3) uint32 array."""
    if len(data) % 12:
        raise ValueError(f"malformed index buffer: {len(data)} bytes")
    return np.frombuffer(data, dtype=_U32).astype(np.uint32).reshape(-1, 3)


def encode_mesh(mesh: Mesh, float32: Optional[bool] = None) -> Any:
    """A proto Mesh (float32: as for as_vertices; None keeps the mesh's own dtype)."""
    return pb.Mesh(name=mesh.name, vertices=pack_vertices(mesh.vertices, float32),
                   indices=pack_triangles(mesh.triangles))


def decode_mesh(message: Any) -> Mesh:
    """A proto Mesh as a Mesh."""
    return Mesh(message.name, unpack_vertices(message.vertices), unpack_triangles(message.indices))


def transform(matrix: ArrayLike) -> Any:
    """A proto Transform (the 3x4 affine map x' = A x + t, row-major) from a (3, 4) or (4, 4)
    matrix, 12 numbers, or a translation (3 numbers)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape == (3,):
        m = np.hstack([np.eye(3), m.reshape(3, 1)])
    elif m.shape == (4, 4):
        m = m[:3]
    elif m.shape == (12,):
        m = m.reshape(3, 4)
    if m.shape != (3, 4):
        raise ValueError("a transform is a (3, 4) or (4, 4) matrix, 12 numbers or a translation "
                         f"(3 numbers), got shape {np.asarray(matrix).shape}")
    return pb.Transform(m=[float(x) for x in m.ravel()])


def transform_matrix(message: Any) -> np.ndarray:
    """A proto Transform as a (3, 4) array."""
    return np.asarray(message.m, dtype=np.float64).reshape(3, 4)
