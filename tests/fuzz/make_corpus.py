#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets (tests/fuzz/corpus/TARGET/): small valid files,
all synthetic (no scan data is committed), each < 64 KiB; the E57 seed is the CC0 synthetic cube
of the scanner samples (data/README.md) and the LAZ seeds are two BSD-licensed PDAL samples
(© Hobu, Inc.), copied when data/get-data has fetched them.
Run from the repository root: python3 tests/fuzz/make_corpus.py
The scene seeds come from tests/fuzz/scene_base (a small scene written by `hapticloud run`)."""
import os
import random
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORPUS = os.path.join(ROOT, "tests", "fuzz", "corpus")
LIMIT = 64 * 1024


def put(target, name, data):
    if isinstance(data, str):
        data = data.encode()
    assert len(data) < LIMIT, (target, name, len(data))
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def surface_points(n):
    """n points of a synthetic wavy patch (no scan data is committed: data/README.md)."""
    import math
    pts = []
    for i in range(n):
        x = -0.05 + 0.1 * ((i * 37) % n) / n
        y = -0.05 + 0.1 * ((i * 53) % n) / n
        pts.append((round(x, 6), round(y, 6), round(0.004 * math.sin(60 * x) * math.cos(40 * y), 6)))
    return pts


def ply_header(fmt, n, props="property float x\nproperty float y\nproperty float z\n", extra=""):
    return f"ply\nformat {fmt} 1.0\ncomment fuzz seed\nelement vertex {n}\n{props}{extra}end_header\n"


def crc32c(data):
    """CRC-32C (Castagnoli, reflected 0x82F63B78): the E57 page checksum (E2807 section 7.3)."""
    c = 0xFFFFFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
    return c ^ 0xFFFFFFFF


def e57_two_scans():
    """A synthetic E57 (E2807) of two data3D scans, written from the specification: scan 0 holds
    600 cartesian records as 13-bit ScaledIntegers, an invalid state (2 bits) and a Float single
    intensity whose bounds leave no range (minimum = maximum: normalised by the data's own range), its bytestreams cut into
    packets by bytes so that values straddle packets, an empty packet among them; scan 1 holds 150
    spherical Float double records under a rotated and translated pose. Pages of 1024 bytes, each
    1020 bytes of data and their CRC-32C big-endian."""
    import math

    def bits_pack(values, nbits):
        acc, n, out = 0, 0, bytearray()
        for v in values:
            acc |= v << n
            n += nbits
            while n >= 8:
                out.append(acc & 0xFF)
                acc >>= 8
                n -= 8
        if n:
            out.append(acc & 0xFF)
        return bytes(out)

    def packets(streams, pieces):
        """Data packets holding each bytestream cut into `pieces` slices of about equal bytes."""
        out = b""
        for k in range(pieces):
            bufs = [st[len(st) * k // pieces:len(st) * (k + 1) // pieces] for st in streams]
            body = struct.pack("<H", len(bufs)) + b"".join(struct.pack("<H", len(b)) for b in bufs) + b"".join(bufs)
            pk = bytearray(struct.pack("<BBH", 1, 0, 0) + body)
            while len(pk) % 4:
                pk.append(0)
            struct.pack_into("<H", pk, 2, len(pk) - 1)
            out += bytes(pk)
            if k == 0:
                out += struct.pack("<BBH", 2, 0, 15) + bytes(12)  # an empty packet
        return out

    n0, n1 = 600, 150
    xs = [(i * 37) % 8192 for i in range(n0)]
    ys = [(i * 91 + 5) % 8192 for i in range(n0)]
    zs = [(i * 13 + 1000) % 8192 for i in range(n0)]
    states = [2 if i % 9 == 4 else 1 if i % 13 == 6 else 0 for i in range(n0)]
    inten = [float("nan") if i % 50 == 7 else 3.0 + math.sin(i) for i in range(n0)]
    s0 = [bits_pack(xs, 13), bits_pack(ys, 13), bits_pack(zs, 13), bits_pack(states, 2),
          b"".join(struct.pack("<f", v) for v in inten)]
    rng = [1.0 + 0.001 * i for i in range(n1)]
    az = [0.01 * i for i in range(n1)]
    el = [0.3 - 0.002 * i for i in range(n1)]
    s1 = [b"".join(struct.pack("<d", v) for v in col) for col in (rng, az, el)]
    log = bytearray(48)
    sections = []
    for streams, pieces in ((s0, 7), (s1, 3)):
        while len(log) % 4:
            log.append(0)
        start = len(log)
        body = packets(streams, pieces)
        log += struct.pack("<B7xQQQ", 1, 32 + len(body), 0, 0) + body
        sections.append(start)

    def physical(logical):
        return logical // 1020 * 1024 + logical % 1020

    for start in sections:  # dataPhysicalOffset: the first packet
        struct.pack_into("<Q", log, start + 16, physical(start + 32))
    xml = ('<?xml version="1.0" encoding="UTF-8"?>\n<e57Root type="Structure" '
           'xmlns="http://www.astm.org/COMMIT/E57/2010-e57-v1.0"><data3D type="Vector" allowHeterogeneousChildren="1">'
           '<vectorChild type="Structure"><name type="String"><![CDATA[packed]]></name>'
           f'<points type="CompressedVector" fileOffset="{physical(sections[0])}" recordCount="{n0}"><prototype type="Structure">'
           '<cartesianX type="ScaledInteger" minimum="0" maximum="8191" scale="0.0001" offset="-0.4"/>'
           '<cartesianY type="ScaledInteger" minimum="0" maximum="8191" scale="0.0001" offset="-0.4"/>'
           '<cartesianZ type="ScaledInteger" minimum="0" maximum="8191" scale="0.0001"/>'
           '<cartesianInvalidState type="Integer" minimum="0" maximum="2"/><intensity type="Float" precision="single" minimum="0" maximum="0"/>'
           '</prototype><codecs type="Vector" allowHeterogeneousChildren="1"/></points></vectorChild>'
           '<vectorChild type="Structure"><name type="String"><![CDATA[spherical]]></name><pose type="Structure">'
           '<rotation type="Structure"><w type="Float">0.9</w><x type="Float">0.1</x><y type="Float">-0.3</y>'
           '<z type="Float">0.2</z></rotation><translation type="Structure"><x type="Float">1.5</x>'
           '<y type="Float">-2</y><z type="Float">0.25</z></translation></pose>'
           f'<points type="CompressedVector" fileOffset="{physical(sections[1])}" recordCount="{n1}"><prototype type="Structure">'
           '<sphericalRange type="Float"/><sphericalAzimuth type="Float"/><sphericalElevation type="Float"/>'
           '</prototype><codecs type="Vector" allowHeterogeneousChildren="1"/></points></vectorChild>'
           '</data3D></e57Root>\n').encode()
    while len(log) % 4:
        log.append(0)
    xml_at = len(log)
    log += xml
    while len(log) % 1020:
        log.append(0)
    struct.pack_into("<8sIIQQQQ", log, 0, b"ASTM-E57", 1, 0, len(log) // 1020 * 1024, physical(xml_at), len(xml), 1024)
    out = b""
    for at in range(0, len(log), 1020):
        page = bytes(log[at:at + 1020])
        out += page + struct.pack(">I", crc32c(page))
    return out


def main():
    pts = surface_points(300)
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
    # A scanalyze-style range-grid PLY (obj_info lines, a range_grid list element), synthetic.
    head = ("ply\nformat ascii 1.0\nobj_info num_cols 2\nobj_info num_rows 2\nelement vertex 3\n"
            "property float x\nproperty float y\nproperty float z\nelement range_grid 4\n"
            "property list uchar int vertex_indices\n")
    put("ply", "range_grid.ply", head + "end_header\n" + "".join(f"{x} {y} {z}\n" for x, y, z in few[:3]) +
        "1 0\n1 1\n0\n1 2\n")
    put("ply", "with_faces.ply", ply_header("ascii", 4, extra="element face 2\nproperty list uchar int vertex_indices\n") +
        "0 0 0\n1 0 0\n0 1 0\n1 1 0.5\n3 0 1 2\n3 1 3 2\n")
    put("ply", "list_before.ply", ply_header("ascii", 3, "property list uchar float extra\nproperty float x\n"
        "property float y\nproperty float z\n") + "2 0.5 0.25 1 2 3\n0 4 5 6\n1 7 7 8 9\n")
    # Binary, an element with a list property before the vertices (streamed since 2026-11-26:
    # the stream walks it record by record).
    cams = b"".join(struct.pack("<fB", 0.5 * r, r % 4) + b"".join(struct.pack("<i", 10 * r + k) for k in range(r % 4)) +
                    struct.pack("<h", -r) for r in range(12))
    put("ply", "binary_lists_first.ply", ("ply\nformat binary_little_endian 1.0\nelement junk 3\nproperty short a\n"
        "element camera 12\nproperty float f\nproperty list uchar int ids\nproperty short s\n"
        f"element vertex {len(few)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n").encode() +
        struct.pack("<hhh", 1, 2, 3) + cams + b"".join(struct.pack("<fff", *p) for p in few))
    # Binary, list properties among the vertex's own (streamed since 2026-11-27: records walked
    # one by one), then an element after the vertices.
    verts = b"".join(struct.pack("<fB", r * 0.5 + 1 / 3, r % 3) + b"".join(struct.pack("<i", r + k) for k in range(r % 3)) +
                     struct.pack("<d", -r) + bytes([r, 2 * r, 3 * r]) + struct.pack("<H", r % 2) +
                     b"".join(struct.pack("<f", k + 0.5) for k in range(r % 2)) + struct.pack("<f", r * r * 0.01)
                     for r in range(6))
    put("ply", "vertex_lists.ply", ("ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\n"
        "property list uchar int ids\nproperty double y\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
        "property list ushort float w\nproperty float z\nelement extra 2\nproperty uchar k\nend_header\n").encode() +
        verts + bytes([0, 1]))
    # PCD: ASCII and binary, v0.7 and v0.5 headers.
    put("pcd", "v05.pcd", "# .PCD v.5 - Point Cloud Data file format\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
        "COUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n0 0 0\n0.01 0 0.001\n0 0.01 0.002\n")
    def pcd(data_kind, fields="x y z", size="4 4 4", typ="F F F", count="1 1 1", n=len(few)):
        return (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\n"
                f"TYPE {typ}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
                f"DATA {data_kind}\n")
    put("pcd", "ascii.pcd", pcd("ascii") + "".join(f"{x} {y} {z}\n" for x, y, z in few))
    put("pcd", "binary.pcd", pcd("binary", n=len(pts)).encode() + b"".join(struct.pack("<fff", *p) for p in pts))
    put("pcd", "binary_xyzi.pcd", pcd("binary", "x y z intensity", "4 4 4 4", "F F F F", "1 1 1 1").encode() +
        b"".join(struct.pack("<ffff", x, y, z, 0.5) for x, y, z in few))
    put("pcd", "ascii_double.pcd", pcd("ascii", size="8 8 8") + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in few))
    # binary_compressed (streamed since 2026-11-27): columns x, y, z packed as LZF (liblzf's
    # format: literal runs of up to 32 bytes; z a constant column, one literal value then
    # overlapping back references 4 bytes back, short and long).
    def lzf_literals(data):
        return b"".join(bytes([len(data[i:i + 32]) - 1]) + data[i:i + 32] for i in range(0, len(data), 32))
    def lzf_repeat_back4(length):
        out = b""
        while length > 0:
            n = min(length, 264)
            if n < 3:  # a reference copies 3 bytes at least: the rest as a literal
                return out, n
            field = n - 2
            out += bytes([(field << 5) | 0, 3]) if field < 7 else bytes([(7 << 5) | 0, field - 7, 3])
            length -= n
        return out, 0
    xs = b"".join(struct.pack("<f", x) for x, _, _ in few)
    ys = b"".join(struct.pack("<f", y) for _, y, _ in few)
    zc = struct.pack("<f", 0.5)
    refs, rest = lzf_repeat_back4(4 * len(few) - 4)
    block = lzf_literals(xs + ys) + lzf_literals(zc) + refs + (bytes([rest - 1]) + zc[4 - rest:] if rest else b"")
    unpacked = 12 * len(few)
    put("pcd", "binary_compressed.pcd", pcd("binary_compressed").encode() + struct.pack("<II", len(block), unpacked) + block)
    # OBJ: vertices, with comments, normals, faces, a w component.
    put("obj", "vertices.obj", "# fuzz seed\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in few))
    put("obj", "mesh.obj", "o tri\nv 0 0 0\nv 1 0 0\nv 0 1 0 1.0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1\ng g\nusemtl m\n")
    # XYZ: plain, comments, extra columns, tabs and CRLF.
    put("xyz", "plain.xyz", "".join(f"{x} {y} {z}\n" for x, y, z in pts[:100]))
    put("xyz", "comments.xyz", "# x y z r g b\n" + "".join(f"{x}\t{y}\t{z} 10 20 30\r\n" for x, y, z in few))
    # scanalyze .conf: small hand-made ones.
    put("scanalyze_conf", "one.conf", "camera 0.0 0.0 0.0 0.0 0.0 0.0 1.0\nbmesh s000.ply -0.01 0.02 -0.03 0.1 0.2 0.3 0.9\n")
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
    # Scanner formats (synthetic: written here from the format's public layout).
    put("pts", "xyz.pts", f"{len(few)}\n" + "".join(f"{x} {y} {z}\n" for x, y, z in few))
    put("pts", "xyzirgb.pts", f"{len(few)}\n" + "".join(f"{x} {y} {z} -120 10 20 30\n" for x, y, z in few))
    ptx_head = "3\n2\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0.5 0.25 2 1\n"
    put("ptx", "one_scan.ptx", ptx_head + "".join(f"{x} {y} {z} 0.5 10 20 30\n" for x, y, z in few[:5]) + "0 0 0 0.5 0 0 0\n")
    put("ptx", "two_scans.ptx", (ptx_head + "".join(f"{x} {y} {z} 0.25\n" for x, y, z in few[:6])) * 2)
    for version_minor, pf, rec in ((2, 0, 20), (2, 3, 34), (4, 7, 36)):
        hsize = 375 if version_minor == 4 else 227
        n = len(few)
        hdr = bytearray(hsize)
        hdr[0:4] = b"LASF"
        hdr[24], hdr[25] = 1, version_minor
        struct.pack_into("<HIIBHI", hdr, 94, hsize, hsize, 0, pf, rec, n if pf < 6 else 0)
        scale = 1e-4
        struct.pack_into("<3d3d", hdr, 131, scale, scale, scale, 0.0, 0.0, 0.0)
        struct.pack_into("<6d", hdr, 179, 1, -1, 1, -1, 1, -1)
        if version_minor == 4:
            struct.pack_into("<Q", hdr, 247, n)
        body = b""
        for i, (x, y, z) in enumerate(few):
            r = struct.pack("<iiiH", round(x / scale), round(y / scale), round(z / scale), 100 * i)
            r += bytes(rec - len(r))
            if pf == 3:
                r = r[:28] + struct.pack("<HHH", 256 * i, 512, 65535)
            if pf == 7:
                r = r[:30] + struct.pack("<HHH", 256 * i, 512, 65535)
            body += r
        put("las", f"pf{pf}_1{version_minor}.las", bytes(hdr) + body)
    # E57: the CC0 synthetic cube of libE57Format-test-data (data/README.md credits it), when the
    # scans are present (data/get-data); the synthetic seeds above cover the text formats.
    cube = os.path.join(ROOT, "data", "scans", "scanner_samples", "e57", "libe57-ColourRepresentation.e57")
    if os.path.exists(cube):
        with open(cube, "rb") as f:
            put("e57", "cc0_colour_cube.e57", f.read())
    # E57, synthetic: two scans, bit-packed values straddling packets, invalid states, intensity
    # whose bounds leave no range, spherical coordinates under a pose.
    put("e57", "synthetic_two_scans.e57", e57_two_scans())
    # LAZ: the BSD-licensed PDAL samples (data/README.md credits them, © Hobu, Inc.), a
    # point-wise (LAS 1.2 format 3) and a layered COPC (LAS 1.4 format 7) file, when present.
    for name in ("pdal-simple.laz", "pdal-1.2-with-color.copc.laz"):
        src = os.path.join(ROOT, "data", "scans", "scanner_samples", "laz", name)
        if os.path.exists(src):
            with open(src, "rb") as f:
                put("laz", "bsd_" + name, f.read())
    return 0


if __name__ == "__main__":
    sys.exit(main())
