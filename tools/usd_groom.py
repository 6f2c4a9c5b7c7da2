"""Binary USD grooms against the reference implementation (PyPI's usd-core).

    python tools/usd_groom.py fixtures OUTDIR [STRANDS]
        Writes, with usd-core, the groom files nst3d's USD reader is tested on
        and what usd-core reads from them (facts.json): groom.usdc (a z-up
        BasisCurves groom under a transformed Xform, with widths, displayColor
        and a dozen primvars of other types and interpolations, one indexed,
        one time-sampled, one with elementSize 2), groom.usdz (the same,
        packaged), shot.usda (groom.usdc as a sublayer, with an over that adds
        a primvar), asset.usdc (a prim referencing /Root of groom.usdc, moved)
        and asset.usdz (asset.usdc packaged with the groom it references).
        crates/io/tests/fixtures/usd/ holds them for 6 strands:
            .venv-usd/bin/python tools/usd_groom.py fixtures crates/io/tests/fixtures/usd 6

    python tools/usd_groom.py round-trip NST3D WORKDIR
        The reference round trip: usd-core writes the 100-strand groom as
        .usdc and .usdz; `NST3D strands` stylizes each (to .usdc, .usdz and
        .usda); usd-core opens every output and must find the input's
        topology, upAxis, metersPerUnit, widths, colours and every primvar
        (type, interpolation, elementSize, indices, value, time samples)
        unchanged, and points that moved but stayed near. Exits 1 with what
        differs. tools/test_usd.sh runs it in CI.

The groom is ../shared/data/grooms/Bangs_100.hair (cyHair, y-up), placed
under an Xform turned +90 degrees about x so that it stands z-up in the
stage, as a Blender or Houdini export of it would.
"""
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import time
import zipfile

from pxr import Gf, Sdf, Usd, UsdGeom, UsdUtils, Vt

# usd-core's checks that apply to a groom layer and a package.
VALIDATORS = [
    "usdUtilsValidators:UsdzPackageValidator",
    "usdUtilsValidators:RootPackageValidator",
    "usdUtilsValidators:FileExtensionValidator",
    "usdUtilsValidators:MissingReferenceValidator",
    "usdGeomValidators:StageMetadataChecker",
    "usdValidation:AttributeTypeMismatch",
    "usdValidation:CompositionErrorTest",
    "usdValidation:StageMetadataChecker",
]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BANGS = os.path.join(ROOT, "..", "shared", "data", "grooms", "Bangs_100.hair")
STYLE = os.path.join(ROOT, "..", "shared", "data", "styles", "starry_night.jpg")


def bangs(strands):
    """The first `strands` strands of the cyHair Bangs groom: counts, points."""
    with open(BANGS, "rb") as f:
        data = f.read()
    n, total, bits = struct.unpack_from("<III", data, 4)
    assert data[:4] == b"HAIR" and bits & 3 == 3, "Bangs_100.hair: segments and points expected"
    segs = struct.unpack_from(f"<{n}H", data, 128)
    xyz = struct.unpack_from(f"<{3 * total}f", data, 128 + 2 * n)
    counts = [s + 1 for s in segs][:strands]
    pts = [Gf.Vec3f(*xyz[3 * i : 3 * i + 3]) for i in range(sum(counts))]
    return counts, pts


def author_primvars(curves, counts):
    """Primvars of many types and interpolations, as a groom carries them."""
    n, total = len(counts), sum(counts)
    pv = UsdGeom.PrimvarsAPI(curves)
    T = Sdf.ValueTypeNames

    def make(name, tname, interp, value, element_size=None):
        p = pv.CreatePrimvar(name, tname, interp)
        p.Set(value)
        if element_size:
            p.SetElementSize(element_size)
        return p

    make("clumpId", T.IntArray, "uniform", Vt.IntArray([i // 3 for i in range(n)]))
    make("st", T.TexCoord2fArray, "uniform", [Gf.Vec2f(i / n, 1 - i / n) for i in range(n)])
    make("rootNormal", T.Normal3fArray, "uniform", [Gf.Vec3f(0, 1, 0.01 * i) for i in range(n)])
    make("age", T.Float, "constant", 1.5)
    make("tint", T.Color3f, "constant", Gf.Vec3f(0.2, 0.4, 0.6))
    # Whole-number floats (stored integer-coded) and few distinct values
    # (stored as a lookup table) exercise both compressed float forms.
    make("length", T.FloatArray, "uniform", Vt.FloatArray([float(c) for c in counts]))
    make("kink", T.FloatArray, "vertex", Vt.FloatArray([(0.25, 0.5, 0.125)[i % 3] for i in range(total)]))
    make("weight", T.DoubleArray, "vertex", Vt.DoubleArray([1.0 / (i + 3) for i in range(total)]))
    make("density", T.HalfArray, "vertex", Vt.HalfArray([0.5 + (i % 7) / 8 for i in range(total)]))
    make("region", T.TokenArray, "uniform", Vt.TokenArray(["front" if i % 2 else "side" for i in range(n)]))
    make("groomName", T.String, "constant", 'bangs "100"')
    make("strandId", T.Int64Array, "uniform", Vt.Int64Array([10**12 + i for i in range(n)]))
    make("pair", T.FloatArray, "vertex", Vt.FloatArray([0.1 * i for i in range(2 * total)]), element_size=2)
    # Types whose crate form is special: quaternions (stored real part
    # last), matrices (diagonal ones inlined), asset paths, bools, 64-bit
    # and small integers, time codes, half vectors.
    make("orient", T.QuatfArray, "uniform", [Gf.Quatf(1, 0, 0, 0) if i % 2 else Gf.Quatf(0.5, 0.5, 0.5, 0.5) for i in range(n)])
    make("frame", T.Matrix4d, "constant", Gf.Matrix4d(1, 0, 0, 0, 0, 0.5, 0.25, 0, 0, 0, 2, 0, 3, 4, 5, 1))
    make("squash", T.Matrix2d, "constant", Gf.Matrix2d(2, 0, 0, -1))
    make("map", T.Asset, "constant", Sdf.AssetPath("textures/hair_2.png"))
    make("flag", T.BoolArray, "uniform", Vt.BoolArray([i % 3 == 0 for i in range(n)]))
    make("seed", T.UInt64, "constant", 18000000000000000000)
    make("ids", T.UIntArray, "uniform", Vt.UIntArray([4000000000 + i for i in range(n)]))
    make("shutter", T.TimeCode, "constant", Sdf.TimeCode(24.5))
    make("level", T.UChar, "constant", 200)
    make("offset", T.Half3, "constant", Gf.Vec3h(0.5, 1000, -2))
    make("span", T.Double2, "constant", Gf.Vec2d(1, -2))
    cs = make("cs", T.Color3fArray, "uniform", [Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 0.5, 1)])
    cs.SetIndices(Vt.IntArray([i % 2 for i in range(n)]))
    wind = pv.CreatePrimvar("wind", T.Float, "constant")
    wind.Set(0.25, 1.0)
    wind.Set(0.75, 2.0)


def write_groom(path, strands):
    """A z-up groom stage at `path` (.usdc or .usda by extension)."""
    counts, pts = bangs(strands)
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    root = UsdGeom.Xform.Define(stage, "/Root")
    root.AddTranslateOp().Set(Gf.Vec3d(0.5, -0.25, 2.0))
    root.AddRotateXOp().Set(90.0)
    stage.SetDefaultPrim(root.GetPrim())
    curves = UsdGeom.BasisCurves.Define(stage, "/Root/Hair")
    curves.CreateTypeAttr("linear")
    curves.CreateWrapAttr("nonperiodic")
    curves.CreateCurveVertexCountsAttr(counts)
    curves.CreatePointsAttr(pts)
    total = sum(counts)
    curves.CreateWidthsAttr(Vt.FloatArray([0.004 - 0.002 * (i % 11) / 10 for i in range(total)]))
    curves.SetWidthsInterpolation("vertex")
    curves.CreateDisplayColorPrimvar("vertex").Set([Gf.Vec3f((i % 5) / 4, 0.3, 1 - (i % 3) / 2) for i in range(total)])
    author_primvars(curves, counts)
    stage.GetRootLayer().Save()


def write_composed(folder):
    """shot.usda (sublayers groom.usdc), asset.usdc (references it) and
    asset.usdz (asset.usdc and groom.usdc packaged)."""
    shot = Sdf.Layer.CreateNew(os.path.join(folder, "shot.usda"))
    shot.subLayerPaths.append("./groom.usdc")
    shot.defaultPrim = "Root"
    stage = Usd.Stage.Open(shot)
    stage.SetEditTarget(shot)
    over = stage.OverridePrim("/Root/Hair")
    UsdGeom.PrimvarsAPI(over).CreatePrimvar("shot", Sdf.ValueTypeNames.Int, "constant").Set(7)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    shot.Save()

    asset = Usd.Stage.CreateNew(os.path.join(folder, "asset.usdc"))
    UsdGeom.SetStageUpAxis(asset, UsdGeom.Tokens.z)
    char = UsdGeom.Xform.Define(asset, "/Char")
    char.GetPrim().GetReferences().AddReference("./groom.usdc", "/Root")
    # The reference brings /Root's ops; a stronger translate replaces its own.
    char.GetPrim().CreateAttribute("xformOp:translate", Sdf.ValueTypeNames.Double3).Set(Gf.Vec3d(10, 0, 0))
    asset.SetDefaultPrim(char.GetPrim())
    asset.GetRootLayer().Save()
    ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(os.path.join(folder, "asset.usdc")), os.path.join(folder, "asset.usdz"))
    assert ok, "asset.usdz"


def primvar_facts(pv, values):
    """Everything a primvar is, as plain JSON (its values if `values`)."""
    attr = pv.GetAttr()
    samples = attr.GetTimeSamples()
    out = {
        "type": str(attr.GetTypeName()),
        "interpolation": pv.GetInterpolation(),
        "elementSize": pv.GetElementSize(),
    }
    if values:
        out["indices"] = list(pv.GetIndices()) if pv.IsIndexed() else None
        out["value"] = plain(attr.Get()) if attr.HasAuthoredValue() and not samples else None
        out["samples"] = [[t, plain(attr.Get(t))] for t in samples]
    return out


def plain(v):
    """A USD value as nested lists of numbers and strings (quaternions real
    part first, as text writes them; asset paths and time codes as their
    path and number)."""
    if v is None or isinstance(v, (bool, int, str, float)):
        return v
    if isinstance(v, (Gf.Quatf, Gf.Quatd, Gf.Quath)):
        return [float(v.GetReal())] + [float(x) for x in v.GetImaginary()]
    if isinstance(v, Sdf.AssetPath):
        return v.path
    if isinstance(v, Sdf.TimeCode):
        return v.GetValue()
    if hasattr(v, "__len__") and not isinstance(v, str):
        return [plain(x) for x in v]
    return str(v)


def facts(path, values=True):
    """What usd-core reads from the stage at `path`: per BasisCurves prim (in
    traversal order) counts, world points, widths, displayColor and every
    other primvar (with their values if `values`); the stage's upAxis and
    metersPerUnit."""
    stage = Usd.Stage.Open(path)
    if stage is None:
        sys.exit(f"usd-core could not open {path}")
    prims = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.BasisCurves):
            continue
        c = UsdGeom.BasisCurves(prim)
        xf = c.ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        pvs = {pv.GetName(): primvar_facts(pv, values) for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars() if pv.HasAuthoredValue()}
        prims.append(
            {
                "path": str(prim.GetPath()),
                "curveVertexCounts": list(c.GetCurveVertexCountsAttr().Get()),
                # 9 significant digits: what a float point needs, no more.
                "points": [[float("%.9g" % x) for x in xf.Transform(Gf.Vec3d(p))] for p in c.GetPointsAttr().Get()],
                "widths": list(c.GetWidthsAttr().Get() or []),
                "widthsInterpolation": c.GetWidthsInterpolation(),
                "primvars": pvs,
            }
        )
    return {
        "upAxis": UsdGeom.GetStageUpAxis(stage),
        "metersPerUnit": UsdGeom.GetStageMetersPerUnit(stage),
        "curves": prims,
    }


# A 1x1 grey PNG: the texture primvars:map names, so that packages find it.
PNG = bytes.fromhex(
    "89504e470d0a1a0a0000000d4948445200000001000000010800000000"
    "3a7e9b550000000a49444154789c6360000000020001e221bc330000000049454e44ae426082"
)


def texture(folder):
    os.makedirs(os.path.join(folder, "textures"), exist_ok=True)
    with open(os.path.join(folder, "textures", "hair_2.png"), "wb") as f:
        f.write(PNG)


def fixtures(folder, strands):
    shutil.rmtree(folder, ignore_errors=True)
    os.makedirs(folder)
    texture(folder)
    write_groom(os.path.join(folder, "groom.usdc"), strands)
    ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(os.path.join(folder, "groom.usdc")), os.path.join(folder, "groom.usdz"))
    assert ok, "groom.usdz"
    write_composed(folder)
    names = ["groom.usdc", "groom.usdz", "shot.usda", "asset.usdc", "asset.usdz"]
    # Values once (the other files hold the same primvars), to keep it small.
    table = {n: facts(os.path.join(folder, n), values=n == "groom.usdc") for n in names}
    with open(os.path.join(folder, "facts.json"), "w") as f:
        json.dump(table, f, separators=(",", ":"))
        f.write("\n")


def same(a, b, tol=0.0):
    """Whether two plain values agree (numbers within `tol` relative)."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        try:
            return math.isclose(float(a), float(b), rel_tol=tol, abs_tol=tol)
        except (TypeError, ValueError):
            return False
    return a == b


def compare(inp, out, what):
    """What differs between the input stage's facts and an output's."""
    bad = []
    for key in ("upAxis", "metersPerUnit"):
        if inp[key] != out[key]:
            bad.append(f"{key}: {inp[key]} in, {out[key]} out")
    if len(out["curves"]) != 1:
        return bad + [f"{len(out['curves'])} curves prims out"]
    a, b = inp["curves"][0], out["curves"][0]
    if a["curveVertexCounts"] != b["curveVertexCounts"]:
        bad.append("curveVertexCounts differ")
    pa, pb = a["points"], b["points"]
    if len(pa) != len(pb):
        bad.append(f"{len(pa)} points in, {len(pb)} out")
    else:
        lo = [min(p[k] for p in pa) for k in range(3)]
        hi = [max(p[k] for p in pa) for k in range(3)]
        size = math.dist(lo, hi)
        moved = max(math.dist(p, q) for p, q in zip(pa, pb))
        if not (0 < moved < 0.5 * size) or not all(math.isfinite(x) for p in pb for x in p):
            bad.append(f"points moved up to {moved:.4g} (groom size {size:.4g})")
    if not same(a["widths"], b["widths"]):
        bad.append("widths differ")
    for name, fa in a["primvars"].items():
        fb = b["primvars"].get(name)
        if fb is None:
            bad.append(f"primvar {name} missing")
            continue
        for k in ("type", "interpolation", "elementSize", "indices", "value", "samples"):
            if not same(fa[k], fb[k]):
                bad.append(f"primvar {name}: {k} {str(fa[k])[:60]} in, {str(fb[k])[:60]} out")
    for name in b["primvars"]:
        if name not in a["primvars"]:
            bad.append(f"primvar {name} appeared")
    return [f"{what}: {x}" for x in bad]


def validation_errors(path):
    """What usd-core's validators (where this usd-core has them) and the
    usdz rules (stored entries, data on 64-byte boundaries) find wrong."""
    errors = []
    if path.endswith(".usdz"):
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
                if info.compress_type != zipfile.ZIP_STORED or start % 64:
                    errors.append(f"{info.filename}: compressed or not 64-byte aligned")
    try:
        from pxr import UsdValidation
    except ImportError:
        return errors
    registry = UsdValidation.ValidationRegistry()
    validators = [registry.GetOrLoadValidatorByName(n) for n in VALIDATORS if registry.HasValidator(n)]
    try:
        found = UsdValidation.ValidationContext(validators).Validate(Usd.Stage.Open(path))
    except Exception as e:  # usd-core raises what it cannot open
        return errors + [str(e).strip()]
    return errors + [e.GetMessage() for e in found]


def round_trip(nst3d, work):
    os.makedirs(work, exist_ok=True)
    source = os.path.join(work, "in.usdc")
    for name in ("in.usdc", "in.usdz"):
        p = os.path.join(work, name)
        if os.path.exists(p):
            os.remove(p)
    texture(work)
    write_groom(source, 100)
    ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(source), os.path.join(work, "in.usdz"))
    assert ok, "in.usdz"
    # The fewest iterations and pixels that move every strand: files are
    # under test here, not looks.
    small = ["--preset", "short-hair", "--iters", "3", "--render-size", "64", "--proxies", "20"]
    small += ["--views-per-scale", "1", "--lr-scale", "0.1"]
    problems = []
    for src, out in (("in.usdc", "out.usdc"), ("in.usdz", "out.usdz"), ("in.usdc", "out.usda")):
        args = [nst3d, "strands", "--groom", os.path.join(work, src), "--style", STYLE]
        args += ["--out", os.path.join(work, out)] + small
        start = time.time()
        run = subprocess.run(args, capture_output=True, text=True)
        if run.returncode != 0:
            problems.append(f"{src} -> {out}: nst3d failed: {run.stderr.strip()}")
            continue
        found = compare(facts(os.path.join(work, src)), facts(os.path.join(work, out)), f"{src} -> {out}")
        problems += found
        print(f"{'ok  ' if not found else 'FAIL'} {src} -> {out} ({time.time() - start:.1f} s)")
    for out in ("out.usdc", "out.usdz", "out.usda"):
        problems += [f"{out}: {e}" for e in validation_errors(os.path.join(work, out))]
    for p in problems:
        print(p, file=sys.stderr)
    return 1 if problems else 0


def main():
    if len(sys.argv) >= 3 and sys.argv[1] == "fixtures":
        fixtures(sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 6)
    elif len(sys.argv) == 4 and sys.argv[1] == "round-trip":
        sys.exit(round_trip(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
