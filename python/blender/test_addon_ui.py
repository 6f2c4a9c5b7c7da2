"""The add-on's interactive path, in real Blender with a window (under
Xvfb), on the scene test_addon.py baked and saved:

    xvfb-run -a blender OUTDIR/baked.blend --enable-event-simulate --python-use-system-env \
        -P python/blender/test_addon_ui.py -- UIDIR

(tools/test_blender.sh runs it.) First a real Esc: "Stylize smoke" started
from the UI runs modal with its job in a thread; once the job reports
progress, Esc is sent through the window's event queue
(`Window.event_simulate`, hence --enable-event-simulate): the modal
operator consumes it, the job stops, and the scene and the output folder
are as they were. Then a run to its end: the panel's progress rises while
Blender's event loop keeps running, and the Volume object appears when the
thread ends.
"""

import os
import sys
import time

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import nst3d_blender  # noqa: E402
from nst3d_blender_tests.common import same_state, scene_state  # noqa: E402

OUT = os.path.abspath(sys.argv[sys.argv.index("--") + 1])
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHARED = os.environ.get("NST3D_SHARED", os.path.join(os.path.dirname(REPO), "shared"))
STYLE = os.path.join(SHARED, "data", "styles", "starry_night.jpg")
FRAME = 30
os.makedirs(OUT, exist_ok=True)
nst3d_blender.register()
domain = next(o for o in bpy.data.objects if any(m.type == "FLUID" and m.fluid_type == "DOMAIN" for m in o.modifiers))
state = {}


def done(ok, what):
    print(("ALL OK " if ok else "FAILED: ") + what, flush=True)
    os._exit(0 if ok else 1)


def guarded(fn):
    """A timer callback whose failure ends the test, not leaves Blender open."""
    def call():
        try:
            return fn()
        except Exception as e:
            done(False, f"{fn.__name__}: {type(e).__name__}: {e}")
    return call


def start(iters):
    s = domain.nst3d
    s.style, s.frame_start, s.frame_end, s.iters = STYLE, FRAME, FRAME, iters
    s.output_dir = os.path.join(OUT, "styled")
    win = bpy.context.window_manager.windows[0]
    area = next(a for a in win.screen.areas)
    with bpy.context.temp_override(window=win, area=area, object=domain, active_object=domain):
        r = bpy.ops.nst3d.stylize_smoke("EXEC_DEFAULT")
    print("operator returned", r, flush=True)
    if r != {"RUNNING_MODAL"}:
        done(False, f"the UI path should run modal, got {r}")
    state.update(t0=time.time(), seen=[], ticks=0)


@guarded
def start_cancel():
    state["before"] = scene_state(OUT)
    start(12)
    bpy.app.timers.register(guarded(press_esc), first_interval=0.1)


def press_esc():
    s = domain.nst3d
    if s.message in ("starting", ""):
        if time.time() - state["t0"] > 120:
            done(False, "the job reported no progress")
        return 0.1
    win = bpy.context.window_manager.windows[0]
    win.event_simulate(type="ESC", value="PRESS")
    win.event_simulate(type="ESC", value="RELEASE")
    print(f"sent Esc at '{s.message}'", flush=True)
    state["esc"] = time.time()
    bpy.app.timers.register(guarded(after_esc), first_interval=0.1)
    return None


def after_esc():
    s = domain.nst3d
    changed = same_state(state["before"], scene_state(OUT))
    if not changed:
        print(f"ok: Esc cancelled the modal run in {time.time() - state['esc']:.1f} s; the scene is as it was", flush=True)
        bpy.app.timers.register(guarded(start_full), first_interval=0.1)
        return None
    if time.time() - state["esc"] > 60:
        done(False, f"Esc did not put the scene back (changed: {changed}, status '{s.message}')")
    return 0.1


def start_full():
    start(12)
    bpy.app.timers.register(guarded(watch), first_interval=0.1)


def watch():
    state["ticks"] += 1
    s = domain.nst3d
    state["seen"].append(s.progress)
    if bpy.data.objects.get(domain.name + "_nst3d") is not None:
        rising = sorted(set(round(p, 3) for p in state["seen"]))
        ok = len(rising) >= 3 and state["ticks"] >= 3 and s.message == "done"
        done(ok, f"modal run: {state['ticks']} event-loop ticks while it ran, progress values "
                 f"{rising[:4]}..{rising[-2:]}, status '{s.message}'")
    if time.time() - state["t0"] > 300:
        done(False, f"the job did not finish: '{s.message}'")
    return 0.1


bpy.app.timers.register(start_cancel, first_interval=0.5)
