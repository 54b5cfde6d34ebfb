#!/usr/bin/env python3
"""Generate the mesh and texture assets of the scene corpus (deterministic).

Only numpy and the standard library are used, and every file format is written
by hand (no encoder library whose output could change between versions), so a
rerun reproduces the committed files byte for byte. Geometry is rounded to five
decimals before it is stored, so last-ulp differences in numpy's trigonometry
between machines do not change the bytes either.

Usage (from anywhere):

    python scenes/corpus/make_assets.py           # (re)write the assets
    python scenes/corpus/make_assets.py --check   # exit 1 if any file would change

Files written (paths relative to scenes/corpus/):

    assets/meshes/blob.ply                  binary PLY, normals + uv (icosphere, bumpy)
    assets/meshes/sphere.obj                OBJ, v/vt/vn triangles (uv sphere)
    assets/meshes/matpreview.serialized     Mitsuba serialized (v4), 3 sub-meshes:
                                              0 "ground" (grid, uv), 1 "ball" (normals, uv),
                                              2 "pedestal" (face-normals flag, no uv)
    assets/textures/grid.png                32x32 RGB 8-bit
    assets/textures/mask.png                16x16 grayscale 8-bit (blend weight)
    assets/textures/sky.exr                 32x16 RGB half, uncompressed (lat-long envmap)
    cbox_spectral/meshes/box.obj            OBJ as Blender writes it: quads, mtllib/usemtl
    texture_lab/textures/glyph.png          16x16 RGB 8-bit, asymmetric (shows wrap modes)
"""

from __future__ import annotations

import argparse
import struct
import sys
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DECIMALS = 5


# --------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------


def _r(a: np.ndarray) -> np.ndarray:
    """Round to DECIMALS and convert to float32 (the stored precision)."""
    return np.round(np.asarray(a, np.float64), DECIMALS).astype(np.float32)


def uv_sphere(n_lon: int, n_lat: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit sphere, z up. Returns positions, normals, uvs, triangles (no degenerate ones)."""
    j, i = np.mgrid[0 : n_lat + 1, 0 : n_lon + 1]
    theta = np.pi * j / n_lat  # 0 at +z
    phi = 2 * np.pi * i / n_lon
    p = np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1
    ).reshape(-1, 3)
    uv = np.stack([i / n_lon, 1 - j / n_lat], -1).reshape(-1, 2)
    faces = []
    w = n_lon + 1
    for jj in range(n_lat):
        for ii in range(n_lon):
            a, b = jj * w + ii, jj * w + ii + 1
            c, d = (jj + 1) * w + ii, (jj + 1) * w + ii + 1
            if jj != 0:
                faces.append((a, c, b))
            if jj != n_lat - 1:
                faces.append((b, c, d))
    p = _r(p)
    return p, p.copy(), _r(uv), np.array(faces, np.uint32)


def _midpoint_fn(verts: list[np.ndarray], cache: dict[tuple[int, int], int]):
    """Index of the (normalised) midpoint of edge a-b, created once per edge."""

    def mid(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    return mid


def icosphere(subdiv: int) -> tuple[np.ndarray, np.ndarray]:
    t = (1 + 5**0.5) / 2
    v = [
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
        (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
        (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1),
    ]  # fmt: skip
    f = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    verts = [np.array(x, np.float64) / np.linalg.norm(x) for x in v]
    faces = list(f)
    for _ in range(subdiv):
        cache: dict[tuple[int, int], int] = {}
        mid = _midpoint_fn(verts, cache)
        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, np.uint32)


def vertex_normals(p: np.ndarray, f: np.ndarray) -> np.ndarray:
    p64 = p.astype(np.float64)
    fn = np.cross(p64[f[:, 1]] - p64[f[:, 0]], p64[f[:, 2]] - p64[f[:, 0]])
    n = np.zeros_like(p64)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def blob() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bumpy icosphere (a stand-in for a scanned object), radius about 1, z up."""
    d, f = icosphere(2)
    bump = 1 + 0.12 * np.sin(3 * d[:, 0]) * np.sin(3 * d[:, 1] + 0.5) + 0.08 * d[:, 2]
    p = _r(d * bump[:, None])
    n = _r(vertex_normals(p, f))
    uv = _r(
        np.stack(
            [0.5 + np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 0.5 + np.arcsin(d[:, 2]) / np.pi],
            -1,
        )
    )
    return p, n, uv, f


def grid_plane(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[-1,1]^2 plane at z=0 (normal +z), n x n quads, uv in [0,1]^2."""
    j, i = np.mgrid[0 : n + 1, 0 : n + 1]
    p = np.stack([2 * i / n - 1, 2 * j / n - 1, np.zeros_like(i, np.float64)], -1).reshape(-1, 3)
    uv = np.stack([i / n, j / n], -1).reshape(-1, 2)
    faces = []
    for jj in range(n):
        for ii in range(n):
            a, b = jj * (n + 1) + ii, jj * (n + 1) + ii + 1
            c, d = a + n + 1, b + n + 1
            faces += [(a, b, d), (a, d, c)]
    return _r(p), _r(uv), np.array(faces, np.uint32)


def pedestal(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder of radius 1 from z=0 to z=1 (n sides), outward winding."""
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.stack([np.cos(ang), np.sin(ang)], -1)
    bottom = np.concatenate([ring, np.zeros((n, 1))], 1)
    top = np.concatenate([ring, np.ones((n, 1))], 1)
    p = np.concatenate([bottom, top, [[0, 0, 0], [0, 0, 1]]])
    cb, ct = 2 * n, 2 * n + 1
    faces = []
    for k in range(n):
        k2 = (k + 1) % n
        faces += [(k, k2, n + k2), (k, n + k2, n + k), (ct, n + k, n + k2), (cb, k2, k)]
    return _r(p), np.array(faces, np.uint32)


# --------------------------------------------------------------------------------------
# mesh writers
# --------------------------------------------------------------------------------------


def ply_binary(p: np.ndarray, n: np.ndarray, uv: np.ndarray, f: np.ndarray) -> bytes:
    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment sensaov scene corpus (make_assets.py)\n"
        f"element vertex {len(p)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property float u\nproperty float v\n"
        f"element face {len(f)}\n"
        "property list uchar int vertex_indices\n"
        "end_header\n"
    ).encode("ascii")
    vert = np.concatenate([p, n, uv], 1).astype("<f4")
    face = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = f
    return header + vert.tobytes() + face.tobytes()


def _fmt(row: np.ndarray) -> str:
    return " ".join(f"{x:.5f}" for x in row)


def obj_triangles(p: np.ndarray, n: np.ndarray, uv: np.ndarray, f: np.ndarray, name: str) -> bytes:
    lines = ["# sensaov scene corpus (make_assets.py)", f"o {name}"]
    lines += [f"v {_fmt(x)}" for x in p]
    lines += [f"vt {_fmt(x)}" for x in uv]
    lines += [f"vn {_fmt(x)}" for x in n]
    lines += ["s 1"]
    lines += ["f " + " ".join(f"{k + 1}/{k + 1}/{k + 1}" for k in tri) for tri in f]
    return ("\n".join(lines) + "\n").encode("ascii")


def obj_box() -> bytes:
    """Unit cube [-1,1]^3 the way Blender exports it: quads, shared v/vt/vn pools, usemtl."""
    v = [
        (1, 1, -1), (1, -1, -1), (1, 1, 1), (1, -1, 1),
        (-1, 1, -1), (-1, -1, -1), (-1, 1, 1), (-1, -1, 1),
    ]  # fmt: skip
    vt = [(0, 0), (1, 0), (1, 1), (0, 1)]
    vn = [(0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (1, 0, 0), (0, 0, -1)]
    quads = [  # (v indices, normal index), counter-clockwise seen from outside
        ((1, 5, 7, 3), 1), ((4, 3, 7, 8), 2), ((8, 7, 5, 6), 3),
        ((6, 2, 4, 8), 4), ((2, 1, 3, 4), 5), ((6, 5, 1, 2), 6),
    ]  # fmt: skip
    lines = [
        "# Blender-style OBJ export (sensaov scene corpus, make_assets.py)",
        "mtllib box.mtl",
        "o Cube",
    ]
    lines += [f"v {_fmt(np.array(x, float))}" for x in v]
    lines += [f"vt {_fmt(np.array(x, float))}" for x in vt]
    lines += [f"vn {_fmt(np.array(x, float))}" for x in vn]
    lines += ["s off", "usemtl Material"]
    for vi, ni in quads:
        lines.append("f " + " ".join(f"{a}/{t + 1}/{ni}" for t, a in enumerate(vi)))
    return ("\n".join(lines) + "\n").encode("ascii")


def serialized(meshes: list[dict]) -> bytes:
    """Mitsuba's .serialized format, version 4 (see src/shapes/serialized.cpp).

    Per mesh: uint16 0x041C, uint16 version, then a zlib stream holding
    uint32 flags, the utf-8 name + NUL, uint64 vertex count, uint64 face count,
    positions, [normals], [uvs], uint32 triangle indices. The file ends with one
    uint64 offset per mesh and a uint32 mesh count. Little endian throughout.
    """
    out = b""
    offsets = []
    for m in meshes:
        p, f = m["p"], m["f"]
        flags = 0x1000  # single precision
        body = [p.astype("<f4").tobytes()]
        if m.get("n") is not None:
            flags |= 0x0001
            body.append(m["n"].astype("<f4").tobytes())
        if m.get("uv") is not None:
            flags |= 0x0002
            body.append(m["uv"].astype("<f4").tobytes())
        if m.get("face_normals"):
            flags |= 0x0010
        body.append(f.astype("<u4").tobytes())
        payload = (
            struct.pack("<I", flags)
            + m["name"].encode("utf-8")
            + b"\0"
            + struct.pack("<QQ", len(p), len(f))
            + b"".join(body)
        )
        offsets.append(len(out))
        out += struct.pack("<HH", 0x041C, 0x0004) + zlib.compress(payload, 9)
    out += b"".join(struct.pack("<Q", o) for o in offsets) + struct.pack("<I", len(meshes))
    return out


# --------------------------------------------------------------------------------------
# image writers
# --------------------------------------------------------------------------------------


def png(img: np.ndarray) -> bytes:
    """8-bit PNG, grayscale (H, W) or RGB (H, W, 3), no ancillary chunks."""
    assert img.dtype == np.uint8
    if img.ndim == 2:
        color_type, rows = 0, img
    else:
        assert img.shape[2] == 3
        color_type, rows = 2, img.reshape(img.shape[0], -1)
    h, w = img.shape[:2]
    raw = b"".join(b"\x00" + rows[r].tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + tag
            + data
            + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw, 9))
        + chunk(b"IEND", b"")
    )


def exr_half_rgb(img: np.ndarray) -> bytes:
    """Uncompressed scanline OpenEXR, channels B,G,R as HALF, (H, W, 3) float input."""
    h, w, _ = img.shape

    def attr(name: str, typ: str, data: bytes) -> bytes:
        return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(data)) + data

    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 1, 0, 1, 1) for c in "BGR")
    chlist += b"\0"
    box = struct.pack("<iiii", 0, 0, w - 1, h - 1)
    header = (
        struct.pack("<ii", 20000630, 2)
        + attr("channels", "chlist", chlist)
        + attr("compression", "compression", b"\x00")
        + attr("dataWindow", "box2i", box)
        + attr("displayWindow", "box2i", box)
        + attr("lineOrder", "lineOrder", b"\x00")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    half = img.astype("<f2")
    lines = []
    for y in range(h):
        data = b"".join(half[y, :, c].tobytes() for c in (2, 1, 0))  # B, G, R
        lines.append(struct.pack("<ii", y, len(data)) + data)
    table_start = len(header)
    first = table_start + 8 * h
    offsets, pos = [], first
    for line in lines:
        offsets.append(pos)
        pos += len(line)
    return header + b"".join(struct.pack("<Q", o) for o in offsets) + b"".join(lines)


# --------------------------------------------------------------------------------------
# texture content
# --------------------------------------------------------------------------------------


def grid_texture() -> np.ndarray:
    """32x32: warm-to-cool gradient with a light grid every 8 px and a dark top-left marker."""
    y, x = np.mgrid[0:32, 0:32]
    img = np.empty((32, 32, 3), np.float64)
    img[..., 0] = 200 - 120 * x / 31
    img[..., 1] = 90 + 60 * y / 31
    img[..., 2] = 60 + 150 * x / 31
    lines = (x % 8 == 0) | (y % 8 == 0)
    img[lines] = (235, 230, 215)
    img[2:6, 2:6] = (20, 20, 30)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def mask_texture() -> np.ndarray:
    """16x16 grayscale: soft diagonal stripes (blendbsdf weight)."""
    y, x = np.mgrid[0:16, 0:16]
    v = 0.5 + 0.5 * np.cos(2 * np.pi * (x + y) / 8)
    return np.clip(np.rint(255 * v), 0, 255).astype(np.uint8)


def glyph_texture() -> np.ndarray:
    """16x16 RGB: an 'F' on teal, red right edge, yellow bottom row: asymmetric in u and v."""
    img = np.zeros((16, 16, 3), np.uint8)
    img[:] = (30, 110, 120)
    img[3:13, 4:6] = (245, 240, 225)  # stem
    img[3:5, 4:12] = (245, 240, 225)  # top bar
    img[7:9, 4:10] = (245, 240, 225)  # middle bar
    img[:, 15] = (210, 40, 30)
    img[15, :] = (240, 200, 40)
    return img


def sky_envmap() -> np.ndarray:
    """32x16 lat-long sky: blue zenith, bright horizon band, brown ground, one warm sun blob."""
    h, w = 16, 32
    y, x = np.mgrid[0:h, 0:w]
    t = (y + 0.5) / h  # 0 = top (zenith)
    zenith = np.array([0.25, 0.45, 0.9])
    horizon = np.array([1.0, 0.95, 0.85])
    ground = np.array([0.25, 0.18, 0.12])
    s = np.clip(t / 0.5, 0, 1)[..., None]
    img = np.where((t < 0.5)[..., None], zenith * (1 - s) + horizon * s, ground)
    sun = (x - 8) ** 2 + (y - 4) ** 2 <= 2
    img[sun] = (12.0, 10.0, 7.0)
    return np.round(img, 3)


# --------------------------------------------------------------------------------------


def build() -> dict[str, bytes]:
    files: dict[str, bytes] = {}

    bp, bn, buv, bf = blob()
    files["assets/meshes/blob.ply"] = ply_binary(bp, bn, buv, bf)

    sp, sn, suv, sf = uv_sphere(16, 8)
    files["assets/meshes/sphere.obj"] = obj_triangles(sp, sn, suv, sf, "Sphere")

    gp, guv, gf = grid_plane(4)
    bp2, bn2, buv2, bf2 = uv_sphere(24, 12)
    pp, pf = pedestal(12)
    files["assets/meshes/matpreview.serialized"] = serialized(
        [
            {"name": "ground", "p": gp, "uv": guv, "f": gf},
            {"name": "ball", "p": bp2, "n": bn2, "uv": buv2, "f": bf2},
            {"name": "pedestal", "p": pp, "f": pf, "face_normals": True},
        ]
    )

    files["assets/textures/grid.png"] = png(grid_texture())
    files["assets/textures/mask.png"] = png(mask_texture())
    files["assets/textures/sky.exr"] = exr_half_rgb(sky_envmap())
    files["cbox_spectral/meshes/box.obj"] = obj_box()
    files["texture_lab/textures/glyph.png"] = png(glyph_texture())
    return files


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare with the files on disk")
    args = ap.parse_args()
    changed = []
    total = 0
    for rel, data in build().items():
        path = HERE / rel
        total += len(data)
        same = path.exists() and path.read_bytes() == data
        if not same:
            changed.append(rel)
            if not args.check:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)
        state = "same" if same else ("DIFFERS" if args.check else "written")
        print(f"{rel:45s} {len(data):7d} B  {state}")
    print(f"total {total} B in {len(build())} files")
    if args.check and changed:
        print(f"{len(changed)} file(s) differ from make_assets.py output", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
