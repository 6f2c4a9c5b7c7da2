"""Headless test of the nst3d Blender add-on, in real Blender, two ways:

    # Blender 3.4 (Debian's), the legacy add-on imported from this folder:
    blender -b --factory-startup --python-use-system-env --python-exit-code 1 \
        -P python/blender/test_addon.py -- OUTDIR
    # Blender 4.2+ as a Python module (PyPI's bpy), the extension zip
    # installed and enabled as Blender's Install from Disk does it, on the
    # scene the first run baked:
    python python/blender/test_addon.py -- OUTDIR4 --extension nst3d-VERSION-PLATFORM.zip \
        --baked OUTDIR/baked.blend

(tools/test_blender.sh runs both; `--pictures` renders docs/img's pictures:
larger, 32 samples, 15 iterations.) The first bakes a small Mantaflow smoke
(32 voxels, 30 frames) with ../shared/tools/blender_bake_smoke.py and
saves it as OUTDIR/baked.blend (the bpy module cannot bake: its Mantaflow
fails in its own Python code); then, in both (nst3d_blender_tests/):

- Stylize smoke on the domain for the scene camera, with colour: the new
  Volume object reads a stylized density grid and the colour grid its
  material uses; the camera file the add-on writes frames the domain as
  Blender's projection does; Cycles renders of the original and the
  stylized frame, OUTDIR/blender_smoke_before_after.png;
- Stylize smoke with a feed-forward model (models/starry_density.safetensors);
- Esc during Stylize smoke: the run stops, the scene and an earlier
  result in the output folder are as they were;
- Stylize hair on particle hair (a failed run first), Esc during one
  (the scene as it was), then a hair Curves object with colour rendered
  before and after, OUTDIR/blender_hair_before_after.png.

Without a window, Blender runs operators in place; the Esc tests drive
the add-on's `jobs.Run` (the worker thread and the event handling the
modal operator hands every event to) with timer ticks and Esc, as
Blender's event loop would. test_addon_ui.py sends a real Esc to the
modal operator in a window.
"""

import importlib
import os
import runpy
import sys
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from nst3d_blender_tests import common, hair, smoke  # noqa: E402
from nst3d_blender_tests.common import check  # noqa: E402

ARGS = sys.argv[sys.argv.index("--") + 1:]
OUT = os.path.abspath(ARGS[0])
EXTENSION = os.path.abspath(ARGS[ARGS.index("--extension") + 1]) if "--extension" in ARGS else None
BAKED = os.path.abspath(ARGS[ARGS.index("--baked") + 1]) if "--baked" in ARGS else None
# The docs' pictures: larger, more samples (CI keeps them small).
PICTURES = "--pictures" in ARGS
REPO = os.path.dirname(os.path.dirname(HERE))
SHARED = os.environ.get("NST3D_SHARED", os.path.join(os.path.dirname(REPO), "shared"))
STYLE = os.path.join(SHARED, "data", "styles", "starry_night.jpg")
STYLE_B = os.path.join(SHARED, "data", "styles", "shipwreck.jpg")
MODEL = os.path.join(REPO, "models", "starry_density.safetensors")
FRAME = 30
for need in (STYLE, STYLE_B, MODEL, os.path.join(SHARED, "tools", "blender_bake_smoke.py")):
    if not os.path.exists(need):
        raise SystemExit(f"test data missing: {need}")
os.makedirs(OUT, exist_ok=True)
T0 = time.time()


def smoke_scene():
    """A real Mantaflow bake (32 voxels, 30 frames) with the shared script,
    saved as OUTDIR/baked.blend, or that file opened (--baked)."""
    if BAKED is None:
        sys.argv = ["blender_bake_smoke.py", "--", os.path.join(OUT, "cache"), "32", str(FRAME)]
        runpy.run_path(os.path.join(SHARED, "tools", "blender_bake_smoke.py"), run_name="__main__")
        # Saved with the fluid modifiers off: the bpy module's Mantaflow
        # fails in its own Python code whenever it evaluates them, and the
        # add-on needs the domain's settings and the cache on disk, not the
        # evaluated smoke.
        fluids = [m for o in bpy.data.objects for m in o.modifiers if m.type == "FLUID"]
        for m in fluids:
            m.show_viewport = m.show_render = False
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(OUT, "baked.blend"), copy=True)
        for m in fluids:
            m.show_viewport = m.show_render = True
    else:
        bpy.ops.wm.open_mainfile(filepath=BAKED)
    domain = next(o for o in bpy.data.objects if any(m.type == "FLUID" and m.fluid_type == "DOMAIN" for m in o.modifiers))
    cache = bpy.path.abspath(domain.modifiers["Fluid"].domain_settings.cache_directory)
    check(os.path.exists(os.path.join(cache, "data", f"fluid_data_{FRAME:04d}.vdb")),
          f"the smoke is baked ({time.time() - T0:.0f} s)")
    return domain, os.path.join(cache, "data")


def addon():
    """The add-on's package: the extension, installed from its zip into the
    user repository and enabled, or the legacy add-on, registered."""
    if EXTENSION is None:
        import nst3d_blender

        nst3d_blender.register()
        return nst3d_blender
    repo = next(r for r in bpy.context.preferences.extensions.repos if r.module == "user_default")
    check(repo.directory.startswith(os.environ.get("BLENDER_USER_RESOURCES", "?")),
          f"the user repository is the test's own ({repo.directory})")
    r = bpy.ops.extensions.package_install_files(filepath=EXTENSION, repo="user_default", enable_on_install=True)
    check(r == {"FINISHED"}, f"Blender installs the extension {os.path.basename(EXTENSION)} ({r})")
    name = "bl_ext.user_default.nst3d"
    check(name in bpy.context.preferences.addons, "and enables it")
    import nst3d

    check(nst3d.__file__.startswith(os.path.dirname(repo.directory)),
          f"nst3d comes from the extension's bundled wheel ({nst3d.__file__})")
    return importlib.import_module(name)


def main():
    print(f"Blender {bpy.app.version_string}", flush=True)
    domain, cache = smoke_scene()
    mod = addon()
    scene = bpy.context.scene
    scene.frame_set(FRAME)
    cam = common.setup_render(scene, (288, 384) if PICTURES else (192, 256), 32 if PICTURES else 8)
    cam.location = (0.0, -7.5, 0.9)
    cam.rotation_euler = (1.5707963, 0.0, 0.0)
    cam.data.lens = 100
    domain.hide_render = True
    for o in bpy.data.objects:
        if o.type == "MESH" and o is not domain:
            o.hide_render = True  # the inflow sphere
    smoke.scene_camera(mod, scene, domain, FRAME)
    # The colour's iterations (16 cameras each) are most of the test's time.
    iters = 15 if PICTURES else 4
    styled, pv = smoke.stylize(mod, domain, OUT, cache, STYLE, FRAME, iters, legacy=EXTENSION is None)
    bg = smoke.pictures(mod, scene, domain, styled, pv, FRAME, OUT, cache)
    smoke.model(mod, domain, OUT, MODEL, FRAME)
    smoke.two_paintings(mod, domain, OUT, STYLE, STYLE_B, MODEL, FRAME)
    smoke.cancel(mod, domain, OUT, STYLE, FRAME)
    smoke.bad_output(domain, OUT, STYLE, FRAME)
    scalp = hair.particle_hair()
    hair.particles(mod, scalp, STYLE, OUT)
    hair.cancel(mod, scalp, OUT)
    hair.two_paintings(mod, scalp, STYLE, STYLE_B)
    hair.curves(mod, scene, scalp, STYLE, cam, bg, OUT, (320, 320) if PICTURES else (160, 160))
    print(f"ALL OK ({time.time() - T0:.0f} s)", flush=True)


main()
