"""The add-on's interactive path, in real Blender with a window (under
Xvfb): "Stylize smoke" started from the UI runs in a background thread, the
panel's progress rises while Blender's event loop keeps running, and the
Volume object appears when the thread ends.

    blender -b --factory-startup -P python/blender/test_addon_ui.py -- OUTDIR          # bakes, saves OUTDIR/scene.blend
    xvfb-run -a blender OUTDIR/scene.blend --python-use-system-env -P python/blender/test_addon_ui.py -- OUTDIR

(tools/test_blender.sh runs both.) The first call bakes with the shared
script and saves the scene: a window session's start-up context cannot run
that script.
"""

import os
import runpy
import sys
import time

import bpy

OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1])
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHARED = os.environ.get("NST3D_SHARED", os.path.join(os.path.dirname(REPO), "shared"))
STYLE = os.path.join(SHARED, "data", "styles", "starry_night.jpg")
FRAME = 20
os.makedirs(OUT, exist_ok=True)


def done(ok, what):
    print(("ALL OK " if ok else "FAILED: ") + what, flush=True)
    os._exit(0 if ok else 1)


if bpy.app.background:
    sys.argv = ["blender_bake_smoke.py", "--", os.path.join(OUT, "cache"), "32", str(FRAME)]
    runpy.run_path(os.path.join(SHARED, "tools", "blender_bake_smoke.py"), run_name="__main__")
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(OUT, "scene.blend"))
    print("saved the baked scene", flush=True)
    os._exit(0)

import nst3d_blender  # noqa: E402

nst3d_blender.register()
domain = next(o for o in bpy.data.objects if any(m.type == "FLUID" and m.fluid_type == "DOMAIN" for m in o.modifiers))


def start():
    try:
        run()
    except Exception as e:  # a failure must end the test, not leave Blender open
        done(False, f"{type(e).__name__}: {e}")


def run():
    global seen, ticks, t0
    s = domain.nst3d
    s.style, s.frame_start, s.frame_end, s.iters = STYLE, FRAME, FRAME, 12
    s.output_dir = os.path.join(OUT, "styled")
    win = bpy.context.window_manager.windows[0]
    area = next(a for a in win.screen.areas)
    with bpy.context.temp_override(window=win, area=area, object=domain, active_object=domain):
        r = bpy.ops.nst3d.stylize_smoke("EXEC_DEFAULT")
    print("operator returned", r, flush=True)
    if r != {"RUNNING_MODAL"}:
        done(False, f"the UI path should run modal, got {r}")
    seen, ticks, t0 = [], 0, time.time()
    bpy.app.timers.register(watch, first_interval=0.1)
    return None


def watch():
    global ticks
    ticks += 1
    s = domain.nst3d
    seen.append(s.progress)
    if bpy.data.objects.get(domain.name + "_nst3d") is not None:
        rising = sorted(set(round(p, 3) for p in seen))
        ok = len(rising) >= 3 and ticks >= 3 and s.message == "done"
        done(ok, f"modal run: {ticks} event-loop ticks while it ran, progress values {rising[:4]}..{rising[-2:]}, status '{s.message}'")
    if s.message.startswith("failed") or time.time() - t0 > 300:
        done(False, f"the job did not finish: '{s.message}'")
    return 0.1


bpy.app.timers.register(start, first_interval=0.5)
