"""proxima: the Python client of proximad (API proxima.v1).

    import proxima
    with proxima.Client("127.0.0.1:50051") as client:
        scene = client.create_scene([proxima.box("a", (0, 0, 0), (1, 1, 1)),
                                     proxima.box("b", (1.5, 0, 0), (2.5, 1, 1))])
        result = client.query(scene.scene_id, collisions=True)
        print(result.distances)            # [0.5 0.5]
        client.delete_scene(scene.scene_id)

Geometry goes in and results come out as numpy arrays; every proto message field stays
readable. Failed calls raise ProximaError with the gRPC status code. The generated messages are
`proxima.pb` (proxima_pb2) and the service stub module `proxima.pb_grpc`.
"""
try:
    from ._pb import proxima_pb2 as pb
    from ._pb import proxima_pb2_grpc as pb_grpc
except ImportError as _e:  # the source folder itself, which has no generated stubs
    raise ImportError(
        f"proxima: no generated stubs next to {__file__}: import the package from the build "
        "tree (PYTHONPATH=build/<preset>/python) or pip install ./clients/python") from _e
from .client import (ROUTE_HEADER, UPLOAD_CHUNK_BYTES, Client, FrameStream, RegionResult,
                     RegionStream, ResultStream, ReviewSession, VerifyResult, VerifyStream,
                     read_token_file)
from .errors import ProximaError
from .frames import CULLERS, Result, culler_value, fragment_ids, make_frame
from .geometry import (Mesh, as_triangles, as_vertices, box, decode_mesh, encode_mesh, grid,
                       pack_triangles, pack_vertices, transform, transform_matrix,
                       unpack_triangles, unpack_vertices)

__version__ = "0.1.0"

__all__ = [
    "CULLERS", "Client", "ROUTE_HEADER", "FrameStream", "Mesh", "ProximaError", "RegionResult",
    "RegionStream", "Result", "ResultStream",
    "ReviewSession", "UPLOAD_CHUNK_BYTES", "VerifyResult", "VerifyStream", "as_triangles",
    "as_vertices", "box", "culler_value", "decode_mesh", "encode_mesh", "fragment_ids", "grid",
    "make_frame", "pack_triangles", "pack_vertices", "pb", "pb_grpc", "read_token_file",
    "transform", "transform_matrix", "unpack_triangles", "unpack_vertices",
]
