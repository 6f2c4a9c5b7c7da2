#!/usr/bin/env python3
"""Seeds the fuzz corpora: fuzz/corpus/<reader>/ gets the real files of
../shared/data, the test fixtures, fuzz/seeds/ (files nst3d's own writers
made) and small synthetic files written here, each under its content hash so
re-seeding a grown corpus adds nothing twice.

    python3 tools/fuzz_seeds.py fuzz/corpus [reader ...]

Fails loudly when a real file is missing: a corpus without its seeds would
fuzz something else than the readers see in production.
"""
import hashlib
import json
import os
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.environ.get("NST3D_SHARED", os.path.join(os.path.dirname(ROOT), "shared"))
DATA = os.path.join(SHARED, "data")
FIX = os.path.join(ROOT, "crates")
SEEDS = os.path.join(ROOT, "fuzz", "seeds")


def real(*parts):
    path = os.path.join(*parts)
    if not os.path.isfile(path):
        sys.exit(f"fuzz_seeds.py: seed file missing: {path}")
    with open(path, "rb") as f:
        return f.read()


def f32s(xs):
    return struct.pack(f"<{len(xs)}f", *xs)


def cyhair():
    # 3 strands of 2, 3, 4 points with every optional array (segments,
    # thickness, transparency, colour) and the 88-byte info field.
    segs = [1, 2, 3]
    n = sum(s + 1 for s in segs)
    header = b"HAIR" + struct.pack("<3I", len(segs), n, 0x1F) + struct.pack("<I5f", 2, 0.1, 0.0, 1, 1, 1)
    header += b"fuzz seed".ljust(88, b"\0")
    pts = [c for i in range(n) for c in (i * 0.1, i * 0.2, 1.0 - i * 0.05)]
    body = struct.pack(f"<{len(segs)}H", *segs) + f32s(pts) + f32s([0.01] * n) + f32s([0.5] * n)
    body += f32s([0.2, 0.3, 0.4] * n)
    return header + body


def hairsalon():
    strands = [[(0, 0, 0), (0, 0.1, 0)], [(1, 0, 0), (1, 0.1, 0), (1, 0.2, 0.1)], [(2, 0, 0)]]
    out = struct.pack("<i", len(strands))
    for s in strands:
        out += struct.pack("<i", len(s)) + f32s([c for p in s for c in p])
    return out


def strand_ply_ascii():
    return (
        b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
        b"property float width\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
        b"element strand 2\nproperty ushort nsegs\nend_header\n"
        b"0 0 0 0.01 255 0 0\n0 1 0 0.01 255 0 0\n1 0 0 0.02 0 255 0\n1 1 0 0.02 0 255 0\n1 2 0.5 0.02 0 0 255\n"
        b"1\n2\n"
    )


def mesh_obj():
    return (
        b"# fuzz seed\nmtllib a.mtl\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1 1.0\n"
        b"vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\nvn 0 0 1\ng group\ns off\nusemtl m\n"
        b"f 1/1/1 2/2/1 3/3/2 4\nf -1 -2 -3\nf 1//1 3//1 5//2\nl 1 2\n"
    )


def mesh_ply_ascii():
    return (
        b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        b"property float nx\nproperty float ny\nproperty float nz\nelement face 2\n"
        b"property list uchar int vertex_indices\nend_header\n"
        b"0 0 0 0 0 1\n1 0 0 0 0 1\n1 1 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n4 0 1 2 3\n"
    )


def mesh_ply_binary():
    head = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 2\nproperty list uchar uint vertex_indices\nend_header\n"
    )
    verts = f32s([0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0])
    faces = struct.pack("<B3I", 3, 0, 1, 2) + struct.pack("<B3I", 3, 0, 2, 3)
    return head + verts + faces


CAMERAS = [
    b'{"position": [0, 1, 10], "look_at": [0, 1, 0], "up": [0, 1, 0], "projection": "perspective", '
    b'"focal": 50, "aperture": 41.4214, "resx": 1920, "resy": 1080}',
    b'{"resx": 1280, "resy": 720, "frames": {"1": {"position": [0, 1, 10], "look_at": [0, 1, 0]}, '
    b'"24": {"position": [10, 1, 0], "look_at": [0, 1, 0], "fov": 30}}}',
    b'{"position": [1, 2, 3], "rotation": [-10, 45, 0], "projection": "orthographic", "ortho_width": 4, '
    b'"pixel_aspect": 1.5}',
]


def state_file(kind, meta, arrays):
    """A job state file (crates/job/src/state.rs): safetensors whose
    metadata says the format, the kind of job and its fingerprint; `arrays`
    are (name, dtype, shape, values) with dtype F32, F64 or U64."""
    meta = dict(meta, format="nst3d-state", format_version="1", kind=kind, fingerprint="%016x" % 42, settings="")
    header, data = {"__metadata__": {k: str(v) for k, v in meta.items()}}, b""
    for name, dtype, shape, values in sorted(arrays):
        code = {"F32": "<f", "F64": "<d", "U64": "<Q"}[dtype]
        raw = b"".join(struct.pack(code, v) for v in values)
        header[name] = {"data_offsets": [len(data), len(data) + len(raw)], "dtype": dtype, "shape": shape}
        data += raw
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    return struct.pack("<Q", len(text)) + text + data


def volume_states():
    def state(field, step, shape):
        n = 1
        for d in shape:
            n *= d
        params = [0.1 * i for i in range(n)]
        arrays = [("field", "F32", shape, params), ("adam.m", "F32", [n], [0.01] * n), ("adam.v", "F32", [n], [0.001] * n)]
        return state_file("volume sequence", {"field": field, "step": step}, arrays)

    return [
        state("velocity", 3, [8, 3]),
        state("scale", 0, [8]),
        state_file("volume sequence", {"generation": 4, "octave": 1, "octaves": 3, "sweeps_done": 2}, []),
    ]


def strand_states():
    def v3s(name, n):
        return (name, "F32", [n, 3], [0.1 * i for i in range(3 * n)])

    def strands(name, n_points, offsets):
        return [v3s(name + ".points", n_points), (name + ".offsets", "U64", [len(offsets)], offsets)]

    def image(name, c, h, w):
        return (name, "F32", [c, h, w], [0.5] * (c * h * w))

    tail = [("sums", "F64", [4], [0.1] * 4), ("flicker_sums", "F64", [3], [0.1] * 3)]
    counts = {"frames": 2, "pairs": 1}
    empty = state_file("groom sequence", counts, tail)
    view = [0, 0, 0, 1, 0, 0, 1, 0, 1, 0, 1, 0, 0, 3.0, 40.0, 0.01, 0.5, 0.3, 1.0, 1.0, 1.0, 1, 1, 1, 0.1, 1.0]
    arrays = tail + [("topology", "U64", [2], [2, 3]), ("view", "F32", [26], view)]
    arrays += [v3s("previous.samples", 4), v3s("previous.velocities", 4)]
    arrays += strands("previous.undeformed", 5, [0, 2, 5]) + strands("previous.output", 5, [0, 2, 5])
    arrays += [image("previous.render_output", 3, 2, 2), image("previous.render_input", 3, 2, 2)]
    arrays += [v3s("one_euro.x", 5), v3s("one_euro.d", 5)]
    full = state_file("groom sequence", dict(counts, **{"view.output": "grey_alpha"}), arrays)
    return [empty, full]


def seeds():
    g = lambda name: real(DATA, "grooms", name)  # noqa: E731
    fixture = lambda crate, name: real(FIX, crate, "tests", "fixtures", name)  # noqa: E731
    own = lambda name: real(SEEDS, name)  # noqa: E731
    return {
        "vdb": [
            real(DATA, "volumes", "smoke_000001.vdb"),
            real(DATA, "volumes", "plume48", "fluid_data_0001.vdb"),
            own("vdb_zlib_half_vec3.vdb"),
        ],
        "cyhair": [g("Bangs_100.hair"), cyhair()],
        "hairsalon": [g("Bangs_100.data"), hairsalon()],
        "strand_ply": [g("Bangs_100_binary.ply"), strand_ply_ascii()],
        "usda": [g("basisCurves.usda"), fixture("io", "groom_bangs.usda"), fixture("io", "usd/shot.usda")],
        "usdc": [fixture("io", "usd/groom.usdc"), fixture("io", "usd/asset.usdc"), own("groom_nst3d.usdc")],
        "usdz": [fixture("io", "usd/groom.usdz"), fixture("io", "usd/asset.usdz"), own("groom_nst3d.usdz")],
        "alembic": [g("Bangs_100.abc")],
        "mesh_obj": [mesh_obj(), real(DATA, "meshes", "spot.obj")],
        "mesh_ply": [mesh_ply_ascii(), mesh_ply_binary(), g("Bangs_head.ply")],
        "pth_legacy": [fixture("weights", "nested_legacy.pth"), fixture("weights", "state_legacy.pth")],
        "pth_zip": [
            fixture("weights", "int64_zip.pth"),
            fixture("weights", "nested_zip.pth"),
            fixture("weights", "state_zip.pth"),
        ],
        "safetensors": [fixture("weights", "state.safetensors"), own("model_c1.safetensors")],
        "model": [own("model_c1.safetensors")],
        "camera_json": CAMERAS,
        "volume_state": volume_states(),
        "strand_state": strand_states(),
    }


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    out, wanted = sys.argv[1], sys.argv[2:]
    table = seeds()
    for reader in wanted or table:
        if reader not in table:
            sys.exit(f"fuzz_seeds.py: no seeds for reader '{reader}'")
        folder = os.path.join(out, reader)
        os.makedirs(folder, exist_ok=True)
        for data in table[reader]:
            path = os.path.join(folder, "seed-" + hashlib.sha1(data).hexdigest())
            if not os.path.exists(path):
                with open(path, "wb") as f:
                    f.write(data)


if __name__ == "__main__":
    main()
