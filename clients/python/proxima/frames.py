"""Frames (the changes and queries of one step) and their results, with numpy views."""
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from ._pb import proxima_pb2 as pb
from .geometry import ArrayLike, Mesh, encode_mesh, pack_vertices

# Culler names from the proto's enum: CULLER_VORONOI_CPU is "voronoi-cpu".
CULLERS: Dict[str, int] = {name[len("CULLER_"):].lower().replace("_", "-"): value
                           for name, value in pb.Culler.items()}


def culler_value(culler: Union[str, int]) -> int:
    """The Culler enum value of a name ("auto", "brute", "bvh", "voronoi-cpu", "voronoi-gpu";
    "voronoi_cpu" and "CULLER_VORONOI_CPU" work too) or of an enum value. Raises ValueError
    naming the valid names for anything else."""
    if isinstance(culler, int) and not isinstance(culler, bool):
        if culler in CULLERS.values():
            return culler
    elif isinstance(culler, str):
        key = culler.strip().lower().replace("_", "-")
        key = key[len("culler-"):] if key.startswith("culler-") else key
        if key in CULLERS:
            return CULLERS[key]
    raise ValueError(f"unknown culler {culler!r}; valid cullers: {', '.join(CULLERS)}")


def make_frame(scene_id: str = "", frame: int = 0,
               positions: Optional[Mapping[int, ArrayLike]] = None,
               topology_changes: Optional[Mapping[int, Sequence[Mesh]]] = None,
               additions: Sequence[Mesh] = (), removals: Iterable[int] = (),
               separation: bool = True, self_query: bool = False, collisions: bool = False,
               tolerance: Optional[float] = None, pns: bool = False,
               culler: Union[str, int] = "auto", self_points: bool = False, ccd: bool = False,
               ccd_min_distance: Optional[float] = None, penetration: bool = False,
               voronoi_cell: Optional[float] = None, float32: Optional[bool] = None) -> Any:
    """One Frame (proto): changes by daemon object id, then the queries to run.

    - `positions`: {object id: (N, 3) new vertices, same count and order}
    - `topology_changes`: {object id: [Mesh fragments that replace it]}
    - `additions`: new objects; `removals`: object ids
    - queries: `separation` (per object, the closest other object), `self_query` (per triangle,
      the closest non-adjacent triangle of the same object; `self_points` adds the points),
      `collisions` (intersecting triangle pairs), `tolerance` (pairs within this distance),
      `pns` (pairs whose separation is within the tolerance of the closest), `ccd` (continuous
      collisions from the previous positions to these; `ccd_min_distance` reports contact
      closer than that), `penetration` (penetration vectors of intersecting pairs; implies
      collisions), `culler` (a name from CULLERS), `voronoi_cell` (the Voronoi cullers' cell)
    - `float32`: send vertices as float32 (None: each array's own dtype)
    """
    f = pb.Frame(scene_id=scene_id, frame=frame, removals=[int(r) for r in removals])
    for object_id, vertices in (positions or {}).items():
        f.positions.add(object_id=int(object_id), vertices=pack_vertices(vertices, float32))
    for object_id, fragments in (topology_changes or {}).items():
        f.topology_changes.add(object_id=int(object_id),
                               fragments=[encode_mesh(m, float32) for m in fragments])
    f.additions.extend(encode_mesh(m, float32) for m in additions)
    q = f.queries
    q.separation, q.self, q.collisions, q.pns = separation, self_query, collisions, pns
    q.culler = culler_value(culler)
    q.self_points = self_points
    q.ccd = ccd
    q.penetration = penetration
    if tolerance is not None:
        q.tolerance = tolerance
    if ccd_min_distance is not None:
        q.ccd_min_distance = ccd_min_distance
    if voronoi_cell is not None:
        q.voronoi_cell = voronoi_cell
    return f


def _vec3s(points: Iterable[Any]) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in points], dtype=np.float64).reshape(-1, 3)


def _feature_pairs(pairs: Sequence[Any]) -> Tuple[np.ndarray, np.ndarray]:
    ids = np.array([(p.object, p.triangle, p.other, p.other_triangle) for p in pairs],
                   dtype=np.int64).reshape(-1, 4)
    return ids, np.array([p.distance for p in pairs], dtype=np.float64)


class Result:
    """One FrameResult with numpy views. Every proto field is readable directly
    (`result.separation[0].distance`, `result.stats.culler`; `raw` is the message itself); the
    properties below give arrays. Objects are indices in result order (`object_ids` maps them
    to daemon ids); triangles are indices in each object's index buffer."""

    def __init__(self, raw: Any):
        self.raw = raw

    def __getattr__(self, name: str) -> Any:
        if name == "raw":
            raise AttributeError(name)
        return getattr(self.raw, name)

    def __repr__(self) -> str:
        return f"Result(scene_id={self.raw.scene_id!r}, frame={self.raw.frame})"

    @property
    def ids(self) -> np.ndarray:
        """(n,) uint64: the daemon id of each object, in result order."""
        return np.array(self.raw.object_ids, dtype=np.uint64)

    # Separation: one entry per object.
    @property
    def distances(self) -> np.ndarray:
        """(n,) separation distance of each object (+inf for an object alone in its scene)."""
        return np.array([s.distance if s.has_other else np.inf for s in self.raw.separation],
                        dtype=np.float64)

    @property
    def closest_objects(self) -> np.ndarray:
        """(n,) result index of each object's closest other object (-1 when alone)."""
        return np.array([s.other if s.has_other else -1 for s in self.raw.separation],
                        dtype=np.int64)

    @property
    def closest_triangles(self) -> np.ndarray:
        """(n, 2): the closest triangle of each object and of its closest other object."""
        return np.array([(s.triangle, s.other_triangle) for s in self.raw.separation],
                        dtype=np.int64).reshape(-1, 2)

    @property
    def closest_points(self) -> np.ndarray:
        """(n, 2, 3): the closest point on each object and on its closest other object."""
        s = self.raw.separation
        return np.stack([_vec3s(x.point for x in s), _vec3s(x.other_point for x in s)], axis=1)

    # Self query: one entry per object, each per triangle.
    def self_closest(self, index: int) -> np.ndarray:
        """(T,) int64: for each triangle of object `index`, its closest non-adjacent triangle
        (-1 when every other triangle is adjacent)."""
        return np.array(self.raw.self[index].closest, dtype=np.int64)

    def self_distances(self, index: int) -> np.ndarray:
        """(T,) float64: each triangle's self distance (+inf where self_closest is -1)."""
        return np.array(self.raw.self[index].distance, dtype=np.float64)

    def self_points(self, index: int) -> np.ndarray:
        """(T, 2, 3): each triangle's closest point pair (the frame needs self_points)."""
        return np.array(self.raw.self[index].points, dtype=np.float64).reshape(-1, 2, 3)

    # Pair queries: rows (object, triangle, other, other_triangle).
    @property
    def collision_pairs(self) -> np.ndarray:
        """(K, 4) int64 rows (object, triangle, other, other_triangle) of intersecting pairs."""
        return _feature_pairs(self.raw.collisions)[0]

    @property
    def tolerance_pairs(self) -> np.ndarray:
        """(K, 4) rows as for collision_pairs: the pairs within the tolerance."""
        return _feature_pairs(self.raw.tolerance)[0]

    @property
    def tolerance_distances(self) -> np.ndarray:
        """(K,) the distance of each tolerance pair."""
        return _feature_pairs(self.raw.tolerance)[1]

    @property
    def pns_pairs(self) -> np.ndarray:
        """(K, 4) rows as for collision_pairs: the PNS pairs."""
        return _feature_pairs(self.raw.pns)[0]

    @property
    def pns_distances(self) -> np.ndarray:
        """(K,) the distance of each PNS pair."""
        return _feature_pairs(self.raw.pns)[1]

    # CCD.
    @property
    def ccd_pairs(self) -> np.ndarray:
        """(K, 5) int64 rows (kind, object, primitive, other, other_primitive); kind is
        CCD_VERTEX_FACE (0: a vertex id, a triangle id) or CCD_EDGE_EDGE (1: two edge indices,
        positions in the object's sorted list of unique edges; ccd_vertices names their vertices)."""
        return np.array([(p.kind, p.object, p.primitive, p.other, p.other_primitive)
                         for p in self.raw.ccd.pairs], dtype=np.int64).reshape(-1, 5)

    @property
    def ccd_vertices(self) -> np.ndarray:
        """(K, 2, 3) int64: for each CCD pair, [0] the primitive's vertex ids and [1] the other
        primitive's, in your vertex buffers' numbering (vertex-face: [v, -1, -1] and the
        triangle's three corners; edge-edge: each edge's two vertices, then -1)."""
        def padded(ids: Any) -> list:
            return list(ids) + [-1] * (3 - len(ids))
        return np.array([(padded(p.vertices), padded(p.other_vertices))
                         for p in self.raw.ccd.pairs], dtype=np.int64).reshape(-1, 2, 3)

    @property
    def ccd_toi(self) -> np.ndarray:
        """(K,) time of impact in [0, 1] of each CCD pair (never later than the true one)."""
        return np.array([p.toi for p in self.raw.ccd.pairs], dtype=np.float64)

    @property
    def ccd_earliest(self) -> Optional[Any]:
        """The scene's earliest CcdPair, or None when nothing meets."""
        c = self.raw.ccd
        return c.pairs[c.earliest] if c.has_earliest else None

    # Penetration.
    @property
    def penetration_objects(self) -> np.ndarray:
        """(K, 2) int64 (object, other) of each penetration (other == object: self)."""
        return np.array([(p.object, p.other) for p in self.raw.penetrations],
                        dtype=np.int64).reshape(-1, 2)

    @property
    def penetration_vectors(self) -> np.ndarray:
        """(K, 3): moving `object` by this vector separates it locally."""
        return _vec3s(p.vector for p in self.raw.penetrations)

    @property
    def penetration_depths(self) -> np.ndarray:
        """(K,) the depth of each penetration."""
        return np.array([p.depth for p in self.raw.penetrations], dtype=np.float64)


def fragment_ids(result: Result) -> List[np.ndarray]:
    """The new ids of each topology change's fragments, in order."""
    return [np.array(f.ids, dtype=np.uint64) for f in result.raw.fragment_ids]
