#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets (tests/fuzz/corpus/TARGET/): small valid files,
hand-made or cut from the shared bunny scans (data/scans/bunny, data/get-data), each < 64 KiB.
Run from the repository root: python3 tests/fuzz/make_corpus.py
The scene seeds come from tests/fuzz/scene_base (a small scene written by `hapticloud run`)."""
import os
import random
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORPUS = os.path.join(ROOT, "tests", "fuzz", "corpus")
BUNNY = os.path.join(ROOT, "data", "scans", "bunny")
LIMIT = 64 * 1024


def put(target, name, data):
    if isinstance(data, str):
        data = data.encode()
    assert len(data) < LIMIT, (target, name, len(data))
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def bunny_points(n):
    """n points of bun000.ply (ASCII, x y z per line after end_header)."""
    with open(os.path.join(BUNNY, "bun000.ply"), "rb") as f:
        body = f.read().split(b"end_header\n", 1)[1]
    pts = []
    for line in body.split(b"\n")[: n]:
        x, y, z = (float(v) for v in line.split()[:3])
        pts.append((x, y, z))
    return pts


def ply_header(fmt, n, props="property float x\nproperty float y\nproperty float z\n", extra=""):
    return f"ply\nformat {fmt} 1.0\ncomment fuzz seed\nelement vertex {n}\n{props}{extra}end_header\n"


def main():
    pts = bunny_points(300)
    few = pts[:40]
    # PLY: ASCII, binary little and big endian, doubles, extra properties, a range grid, faces.
    put("ply", "ascii.ply", ply_header("ascii", len(few)) + "".join(f"{x} {y} {z}\n" for x, y, z in few))
    put("ply", "binary_le.ply", ply_header("binary_little_endian", len(pts)).encode() +
        b"".join(struct.pack("<fff", *p) for p in pts))
    put("ply", "binary_be.ply", ply_header("binary_big_endian", len(few)).encode() +
        b"".join(struct.pack(">fff", *p) for p in few))
    put("ply", "double_rgb.ply", ply_header("binary_little_endian", len(few),
        "property double x\nproperty double y\nproperty double z\nproperty uchar red\nproperty uchar green\n"
        "property uchar blue\n").encode() + b"".join(struct.pack("<dddBBB", x, y, z, 200, 100, 50) for x, y, z in few))
    with open(os.path.join(BUNNY, "bun000.ply"), "rb") as f:
        raw = f.read()
    head = raw.split(b"end_header\n", 1)[0].decode()
    head = head.replace("element vertex 40256", "element vertex 60").replace("element range_grid 204800",
                                                                             "element range_grid 4")
    body = raw.split(b"end_header\n", 1)[1].split(b"\n")[:60]
    put("ply", "range_grid.ply", head + "end_header\n" + "\n".join(l.decode() for l in body) + "\n1 0\n1 1\n0\n1 2\n")
    put("ply", "with_faces.ply", ply_header("ascii", 4, extra="element face 2\nproperty list uchar int vertex_indices\n") +
        "0 0 0\n1 0 0\n0 1 0\n1 1 0.5\n3 0 1 2\n3 1 3 2\n")
    put("ply", "list_before.ply", ply_header("ascii", 3, "property list uchar float extra\nproperty float x\n"
        "property float y\nproperty float z\n") + "2 0.5 0.25 1 2 3\n0 4 5 6\n1 7 7 8 9\n")
    # PCD: ASCII and binary, v0.7 and v0.5 (the bunny's own header).
    with open(os.path.join(BUNNY, "pcl_bunny.pcd"), "rb") as f:
        put("pcd", "pcl_bunny.pcd", f.read())
    def pcd(data_kind, fields="x y z", size="4 4 4", typ="F F F", count="1 1 1", n=len(few)):
        return (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\n"
                f"TYPE {typ}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
                f"DATA {data_kind}\n")
    put("pcd", "ascii.pcd", pcd("ascii") + "".join(f"{x} {y} {z}\n" for x, y, z in few))
    put("pcd", "binary.pcd", pcd("binary", n=len(pts)).encode() + b"".join(struct.pack("<fff", *p) for p in pts))
    put("pcd", "binary_xyzi.pcd", pcd("binary", "x y z intensity", "4 4 4 4", "F F F F", "1 1 1 1").encode() +
        b"".join(struct.pack("<ffff", x, y, z, 0.5) for x, y, z in few))
    put("pcd", "ascii_double.pcd", pcd("ascii", size="8 8 8") + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in few))
    # OBJ: vertices, with comments, normals, faces, a w component.
    put("obj", "vertices.obj", "# fuzz seed\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in few))
    put("obj", "mesh.obj", "o tri\nv 0 0 0\nv 1 0 0\nv 0 1 0 1.0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1\ng g\nusemtl m\n")
    # XYZ: plain, comments, extra columns, tabs and CRLF.
    put("xyz", "plain.xyz", "".join(f"{x} {y} {z}\n" for x, y, z in pts[:100]))
    put("xyz", "comments.xyz", "# x y z r g b\n" + "".join(f"{x}\t{y}\t{z} 10 20 30\r\n" for x, y, z in few))
    # scanalyze .conf: the bunny's own, and a small hand-made one.
    with open(os.path.join(BUNNY, "bun.conf"), "rb") as f:
        put("scanalyze_conf", "bun.conf", f.read())
    put("scanalyze_conf", "two.conf", "camera 0 0 -1 0 0 0 1\nbmesh a.ply 0 0 0 0 0 0 1\nmesh b.ply\n"
        "bmesh b.ply.gz 0.1 -0.2 0.3 0.5 0.5 0.5 0.5\n")
    # Run configs: the repository's own (configs/*.yaml) and a few edge cases.
    for name in sorted(os.listdir(os.path.join(ROOT, "configs"))):
        if name.endswith(".yaml"):
            with open(os.path.join(ROOT, "configs", name), "rb") as f:
                put("run_config", name, f.read())
    put("run_config", "flow.yaml", "input: {files: [a.ply, b.ply], conf: a.conf, units: mm}\n"
        "view: {rotation: {euler_deg: [10, 20, 30], order: zyx}, scale: 2}\ngrid: {cell_size_m: 0.001, upsample: auto}\n")
    put("run_config", "quat.yaml", "input:\n  synthetic: {surface: step}\nview:\n  rotation:\n"
        "    quaternion_wxyz: [0.7, 0.1, 0.1, 0.7]\nlayers:\n  friction:\n    mu_s_regions:\n"
        "      - {x_min_m: 0, y_min_m: 0, x_max_m: 1, y_max_m: 1, mu_s: 0.3}\n")
    # Scene folders: scene.yaml and each TIFF layer of tests/fuzz/scene_base.
    base = os.path.join(ROOT, "tests", "fuzz", "scene_base")
    layers = sorted(n for n in os.listdir(base) if n.endswith((".tif", ".tiff", ".png")))
    with open(os.path.join(base, "scene.yaml"), "rb") as f:
        put("scene_yaml", "scene.yaml", f.read())
    for i, name in enumerate(layers):
        with open(os.path.join(base, name), "rb") as f:
            put("scene_tiff", os.path.splitext(name)[0], bytes([i]) + f.read())
    # Falcon frames: byte 0 picks the direction (odd: host → device), byte 1 the read size.
    def nib(v):
        v &= 0xFFFF
        return bytes(0x41 + ((v >> (4 * k)) & 0xF) for k in range(4))
    def frame(axes, b13):
        return b"<" + b"".join(nib(a) for a in axes) + bytes([0x41 + b13, 0x41]) + b">"
    rnd = random.Random(15)
    status = b"".join(frame([rnd.randint(-32768, 32767) for _ in range(3)], rnd.randint(0, 127)) for _ in range(8))
    command = b"".join(frame([rnd.randint(-32768, 32767) for _ in range(3)], rnd.randint(0, 15)) for _ in range(8))
    put("falcon_frames", "status_16", bytes([0, 15]) + status)
    put("falcon_frames", "status_garbage_7", bytes([0, 6]) + b"xx<" + status[:20] + b">>" + status)
    put("falcon_frames", "command_64", bytes([1, 63]) + command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
