#!/usr/bin/env python3
"""Two boxes on proximad: create a scene, query their separation, move one box, query again.

    PYTHONPATH=build/release/python python3 clients/python/examples/example.py HOST:PORT

(or with the package pip-installed). Prints the distance between the boxes before and after the
move (0.5, then 0.25).
"""
import sys

from proxima import Client, ProximaError, box


def main(address: str) -> int:
    a = box("a", (0, 0, 0), (1, 1, 1))
    b = box("b", (1.5, 0, 0), (2.5, 1, 1))
    with Client(address) as client:
        scene = client.create_scene([a, b], name="example")
        try:
            result = client.query(scene.scene_id, collisions=True)
            s = result.separation[0]  # the proto message; result.distances etc. are numpy
            (p, q), (t, u) = result.closest_points[0], result.closest_triangles[0]
            print(f"distance a-b: {s.distance!r} (triangle {t} of a, triangle {u} of b, "
                  f"closest points ({p[0]:g}, {p[1]:g}, {p[2]:g}) and "
                  f"({q[0]:g}, {q[1]:g}, {q[2]:g}))")
            # A frame with new positions for b (same vertex count and order), by its daemon id.
            b_id = scene.objects[1].id
            moved = b.vertices - [0.25, 0, 0]  # an (8, 3) numpy array
            result = client.query(scene.scene_id, frame=1, positions={b_id: moved})
            print(f"after moving b by -0.25 in x: distance a-b: {result.distances[0]!r}")
        finally:
            client.delete_scene(scene.scene_id)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    try:
        sys.exit(main(sys.argv[1]))
    except ProximaError as e:
        print(f"example: error: {e}", file=sys.stderr)
        sys.exit(1)
