#!/usr/bin/env python3
"""Two boxes on proximad: create a scene, query their separation, move one box, query again.

    python3 clients/python/example.py HOST:PORT

Prints the distance between the boxes before and after the move (0.5, then 0.25).
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from proxima_client import Client, ProximaError, box  # noqa: E402


def main(address: str) -> int:
    a = box("a", (0, 0, 0), (1, 1, 1))
    b = box("b", (1.5, 0, 0), (2.5, 1, 1))
    with Client(address) as client:
        scene = client.create_scene([a, b], name="example")
        try:
            result = client.query(scene.scene_id, collisions=True)
            s = result.separation[0]
            print(f"distance a-b: {s.distance!r} (triangle {s.triangle} of a, triangle "
                  f"{s.other_triangle} of b, closest points "
                  f"({s.point.x:g}, {s.point.y:g}, {s.point.z:g}) and "
                  f"({s.other_point.x:g}, {s.other_point.y:g}, {s.other_point.z:g}))")
            # A frame with new positions for b (same vertex count and order), by its daemon id.
            b_id = scene.objects[1].id
            moved = [(x - 0.25, y, z) for x, y, z in b.vertices]
            result = client.query(scene.scene_id, frame=1, positions={b_id: moved})
            print(f"after moving b by -0.25 in x: distance a-b: {result.separation[0].distance!r}")
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
