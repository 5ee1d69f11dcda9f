#!/usr/bin/env python3
"""Writes the hand-made seed inputs of the fuzz targets into corpus/<target>/ (seed-*.bin).

The committed corpus is these seeds plus what fuzzing found, minimized with libFuzzer's -merge=1
(docs/reliability.md). Protobuf messages are encoded by hand (the wire format is simple and this
keeps the script free of a protobuf dependency); field numbers are proto/proxima/v1/proxima.proto's.
"""
import gzip
import os
import struct
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "..", "shared", "data")


def varint(n):
    out = b""
    n &= (1 << 64) - 1
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out += bytes([b | 0x80])
        else:
            return out + bytes([b])


def key(field, wire):
    return varint(field << 3 | wire)


def vi(field, n):
    return key(field, 0) + varint(n)


def ld(field, payload):
    if isinstance(payload, str):
        payload = payload.encode()
    return key(field, 2) + varint(len(payload)) + payload


def dbl(field, x):
    return key(field, 1) + struct.pack("<d", x)


def packed_doubles(field, xs):
    return ld(field, b"".join(struct.pack("<d", x) for x in xs))


TETRA_V = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_T = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def vertex_bytes(vs, f64=True):
    fmt = "<3d" if f64 else "<3f"
    return b"".join(struct.pack(fmt, *v) for v in vs)


def index_bytes(ts):
    return b"".join(struct.pack("<3I", *t) for t in ts)


def vertex_buffer(vs, f64=True):
    return vi(1, 2 if f64 else 1) + ld(2, vertex_bytes(vs, f64))


def mesh(name, vs, ts, f64=True):
    return ld(1, name) + ld(2, vertex_buffer(vs, f64)) + ld(3, index_bytes(ts))


def moved(vs, dx=0.0, dy=0.0, dz=0.0):
    return [(x + dx, y + dy, z + dz) for x, y, z in vs]


def queries(separation=False, self_=False, collisions=False, tolerance=None, pns=False,
            culler=0, self_points=False, ccd=False, ccd_min=None, penetration=False, cell=None):
    q = b""
    q += vi(1, 1) if separation else b""
    q += vi(2, 1) if self_ else b""
    q += vi(3, 1) if collisions else b""
    q += dbl(4, tolerance) if tolerance is not None else b""
    q += vi(5, 1) if pns else b""
    q += vi(6, culler) if culler else b""
    q += vi(7, 1) if self_points else b""
    q += vi(8, 1) if ccd else b""
    q += dbl(9, ccd_min) if ccd_min is not None else b""
    q += vi(10, 1) if penetration else b""
    q += dbl(11, cell) if cell is not None else b""
    return q


def frame(number, positions=(), topology=(), additions=(), removals=(), q=b""):
    f = ld(1, "fuzz-scene") + vi(2, number)
    for object_id, vs, f64 in positions:
        f += ld(3, vi(1, object_id) + ld(2, vertex_buffer(vs, f64)))
    for object_id, fragments in topology:
        f += ld(4, vi(1, object_id) + b"".join(ld(2, m) for m in fragments))
    for m in additions:
        f += ld(5, m)
    for r in removals:
        f += vi(6, r)
    if q:
        f += ld(7, q)
    return f


def frames(*fs):
    out = b"\x00"
    for f in fs:
        out += struct.pack("<H", len(f)) + f
    return out


def request_seeds():
    # Object 1 is a tetrahedron at x = 0, object 2 one at x = 2 (fuzz_request.cpp).
    tetra2 = mesh("c", moved(TETRA_V, 0.5, 0.5, 0.5), TETRA_T)
    split_a = mesh("a0", TETRA_V[:3], TETRA_T[:1])
    split_b = mesh("a1", TETRA_V, TETRA_T[1:])
    all_queries = queries(True, True, True, 0.5, True, 0, True)
    yield "frame-queries", frames(frame(1, positions=[(1, moved(TETRA_V, 0.2), True)],
                                        q=all_queries))
    yield "frame-float32", frames(frame(1, positions=[(2, moved(TETRA_V, 1.5), False)],
                                        q=queries(separation=True, culler=1)))
    yield "frame-add-remove", frames(frame(1, additions=[tetra2], removals=[2],
                                           q=queries(collisions=True, culler=2)))
    yield "frame-topology", frames(frame(1, topology=[(1, [split_a, split_b])],
                                         q=queries(self_=True, collisions=True, penetration=True)))
    yield "frame-ccd", frames(frame(1, q=queries(separation=True)),
                              frame(2, positions=[(2, moved(TETRA_V, 1.2, 0.1, 0.1), True)],
                                    q=queries(ccd=True, ccd_min=0.01, collisions=True)))
    yield "frame-voronoi", frames(frame(1, positions=[(2, moved(TETRA_V, 0.9), True)],
                                        q=queries(separation=True, tolerance=0.2, culler=3,
                                                  cell=0.25)))
    # Object 2 sweeps through object 1 with coplanar faces: CCD's degenerate worst case, which
    # the frame's deadline bounds.
    yield "frame-ccd-crossing", frames(frame(1, positions=[(2, moved(TETRA_V, -0.5), True)],
                                             q=queries(ccd=True)))
    yield "frame-penetration", frames(
        frame(1, positions=[(2, moved(TETRA_V, 0.25, 0.25, 0.25), True)],
              q=queries(collisions=True, penetration=True, culler=2)),
        frame(2, additions=[mesh("d", moved(TETRA_V, 0.1), TETRA_T)],
              q=queries(penetration=True, pns=True)))
    create = ld(1, "scene") + ld(2, mesh("a", TETRA_V, TETRA_T)) + \
        ld(2, mesh("b", moved(TETRA_V, 3), TETRA_T, False))
    yield "create-scene", b"\x01" + create
    vb = vertex_bytes(TETRA_V)
    yield "upload-f64", b"\x02\x02" + struct.pack("<H", len(vb)) + vb + index_bytes(TETRA_T)
    vb = vertex_bytes(TETRA_V, False)
    yield "upload-f32", b"\x02\x01" + struct.pack("<H", len(vb)) + vb + index_bytes(TETRA_T)
    identity = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]
    join = ld(1, "room") + ld(2, "plant") + ld(3, "me") + ld(4, mesh("avatar", TETRA_V, TETRA_T)) \
        + dbl(5, 0.05) + vi(6, 1)
    yield "review-join", b"\x03" + ld(1, join)
    yield "review-pose", b"\x03" + ld(2, vi(1, 7) + ld(2, packed_doubles(1, identity)))
    yield "review-move", b"\x03" + ld(3, vi(1, 8) + ld(2, vi(1, 3) + ld(2, packed_doubles(1, identity))))
    yield "review-add", b"\x03" + ld(3, vi(1, 9) + ld(3, mesh("box", TETRA_V, TETRA_T)))
    yield "review-remove", b"\x03" + ld(3, vi(1, 10) + ld(4, vi(1, 3)))


def ply_ascii():
    return ("ply\nformat ascii 1.0\ncomment fuzz seed\nelement vertex 4\nproperty double x\n"
            "property double y\nproperty double z\nelement face 2\n"
            "property list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n4 0 1 3 2\n").encode()


def ply_binary(big):
    e = ">" if big else "<"
    head = ("ply\nformat binary_%s_endian 1.0\nelement vertex 4\nproperty float x\n"
            "property float y\nproperty float z\nproperty uchar red\nelement face 2\n"
            "property list uchar uint vertex_indices\nproperty int flags\nend_header\n"
            % ("big" if big else "little")).encode()
    body = b"".join(struct.pack(e + "3fB", *v, 7) for v in TETRA_V)
    body += struct.pack(e + "B3Ii", 3, 0, 1, 2, 5) + struct.pack(e + "B4Ii", 4, 0, 1, 3, 2, 6)
    return head + body


def off():
    return b"OFF\n# comment\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n4 0 1 3 2\n"


def obj():
    return (b"# fuzz seed\no tetra\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nvt 0 0\n"
            b"g part\nf 1 3 2\nf 1//1 2//1 4//1\nf 1/1 4/1 3/1\nf 2 3 4 1\nl 1 2\np 3\n")


def stl_ascii():
    out = "solid fuzz\n"
    for t in TETRA_T:
        out += " facet normal 0 0 1\n  outer loop\n"
        for i in t:
            out += "   vertex %g %g %g\n" % TETRA_V[i]
        out += "  endloop\n endfacet\n"
    return (out + "endsolid fuzz\n").encode()


def stl_binary():
    out = b"binary seed".ljust(80, b" ") + struct.pack("<I", len(TETRA_T))
    for t in TETRA_T:
        out += struct.pack("<3f", 0, 0, 1)
        for i in t:
            out += struct.pack("<3f", *TETRA_V[i])
        out += struct.pack("<H", 0)
    return out


def gltf_parts():
    import base64
    import json
    vb = b"".join(struct.pack("<3f", *v) for v in TETRA_V)
    ib = b"".join(struct.pack("<3H", *t) for t in TETRA_T)
    buffer = vb + ib
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "children": [1]},
                  {"mesh": 0, "translation": [2, 0, 0], "scale": [1, 2, 1]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 1]},
            {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(vb)},
                        {"buffer": 0, "byteOffset": len(vb), "byteLength": len(ib)}],
        "buffers": [{"byteLength": len(buffer)}],
    }
    return doc, buffer, base64


def gltf():
    import json
    doc, buffer, base64 = gltf_parts()
    doc["buffers"][0]["uri"] = ("data:application/octet-stream;base64," +
                                base64.b64encode(buffer).decode())
    return json.dumps(doc).encode()


def glb():
    import json
    doc, buffer, _ = gltf_parts()
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    buffer += b"\0" * (-len(buffer) % 4)
    chunks = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(buffer), b"BIN\0") + buffer
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def mesh_seeds():
    # First byte: format index into fuzz_mesh.cpp's FORMATS (ply off stl gltf glb); + 5: the same
    # format without welding.
    yield "ply-ascii", b"\x00" + ply_ascii()
    yield "ply-le", b"\x00" + ply_binary(False)
    yield "ply-be", b"\x05" + ply_binary(True)
    yield "off", b"\x01" + off()
    yield "off-noweld", b"\x06" + b"COFF\n3 1 0\n0 0 0 1 0 0 1\n1 0 0 1 0 0 1\n0 1 0 1 0 0 1\n3 0 1 2\n"
    yield "stl-ascii", b"\x02" + stl_ascii()
    yield "stl-binary", b"\x07" + stl_binary()
    yield "gltf", b"\x03" + gltf()
    yield "glb", b"\x04" + glb()
    # gzip data under any format is decompressed first (mesh_io.cpp): a compressed PLY and OFF,
    # and one cut short.
    yield "ply-gz", b"\x00" + gzip.compress(ply_ascii(), mtime=0)
    yield "off-gz", b"\x06" + gzip.compress(off(), mtime=0)
    yield "ply-gz-truncated", b"\x00" + gzip.compress(ply_binary(False), mtime=0)[:-9]


def mesh_obj_seeds():
    yield "obj", obj()
    yield "obj-negative-indices", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1 1\nf -4 -3 -2\nf -4 -2 -1\n"


def md2(frames=2, vertices=4):
    """A tetrahedron (plus unused vertices up to `vertices`) with `frames` keyframes."""
    tris = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    frame_size = 40 + 4 * vertices
    ofs_tris = 68
    ofs_frames = ofs_tris + 12 * len(tris)
    ofs_end = ofs_frames + frames * frame_size
    out = b"IDP2" + struct.pack("<16i", 8, 64, 64, frame_size, 0, vertices, 0, len(tris), 0,
                                 frames, 68, 68, ofs_tris, ofs_frames, ofs_end, ofs_end)
    for t in tris:
        out += struct.pack("<6H", *t, 0, 0, 0)
    for k in range(frames):
        out += struct.pack("<6f", 0.5 + k, 0.5, 0.25, float(k), 0.0, -1.0)
        out += ("pose%d" % k).encode().ljust(16, b"\0")
        for v in range(vertices):
            out += struct.pack("<4B", (v * 37) % 256, (v * 11) % 256, (v * 5) % 256, 0)
    return out


def md2_seeds():
    yield "md2", md2()
    yield "md2-one-frame", md2(frames=1, vertices=6)
    yield "md2-truncated", md2(frames=3)[:-7]


def ccd_seeds():
    rows_vf = ["0,1,0,1,1,1", "0,1,0,1,0,1", "1,1,0,1,0,1", "0,1,1,1,0,1",
               "0,1,0,1,-1,1", "0,1,0,1,0,1", "1,1,0,1,0,1", "0,1,1,1,0,1"]
    yield "vf-hit", ("\n".join(r + ",1" for r in rows_vf) + "\n").encode()
    yield "vf-no-truth", ("\r\n".join(rows_vf) + "\r\n").encode()
    big = "123456789012345678901234567890123456789,3"
    yield "bignum", ("\n".join("%s,%s,-1,7,0,1" % (big, big) for _ in range(8)) + "\n").encode()
    for kind in ("vertex-face", "edge-edge"):
        path = os.path.join(DATA, "ccd-queries", "erleben-spikes", kind, "data_0_0.csv")
        if os.path.exists(path):
            with open(path, "rb") as f:
                lines = f.read().splitlines(keepends=True)
            yield "erleben-spikes-" + kind, b"".join(lines[:16])


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "corpus")
    frame_seeds = [(name, data[1:]) for name, data in request_seeds() if name.startswith("frame")]
    for target, seeds in (("request", request_seeds()), ("frames", frame_seeds),
                          ("mesh", mesh_seeds()),
                          ("mesh_obj", mesh_obj_seeds()), ("md2", md2_seeds()),
                          ("ccd_queries", ccd_seeds())):
        os.makedirs(os.path.join(out, target), exist_ok=True)
        for name, data in seeds:
            with open(os.path.join(out, target, "seed-" + name), "wb") as f:
                f.write(data)


if __name__ == "__main__":
    main()
