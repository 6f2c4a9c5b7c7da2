"""What the add-on's tests share: checks, the scene's state before and
after a run, Cycles renders and before | after sheets."""

import hashlib
import os

import bpy
import numpy as np


def check(cond, what):
    if not cond:
        raise SystemExit(f"FAILED: {what}")
    print(f"ok: {what}", flush=True)


def files_under(path):
    """{relative path: sha256} of every file under `path` (hidden ones too)."""
    out = {}
    for root, _, files in os.walk(path):
        for f in files:
            p = os.path.join(root, f)
            with open(p, "rb") as fh:
                out[os.path.relpath(p, path)] = hashlib.sha256(fh.read()).hexdigest()
    return out


def _curves_points(obj):
    pts = np.empty(len(obj.data.points) * 3, np.float32)
    obj.data.attributes["position"].data.foreach_get("vector", pts)
    return hashlib.sha256(pts.tobytes()).hexdigest()


def scene_state(folder):
    """Everything a run could change: the data-blocks, each object's place,
    settings and strands, the selection, the frame, and the files under
    `folder`."""
    vl = bpy.context.view_layer
    objects = {}
    for o in bpy.data.objects:
        s = o.nst3d
        objects[o.name] = (o.type, tuple(tuple(round(v, 6) for v in row) for row in o.matrix_world),
                           round(s.progress, 6), s.message,
                           _curves_points(o) if o.type == "CURVES" else None,
                           len(o.particle_systems) if o.type == "MESH" else None)
    blocks = {k: sorted(b.name for b in getattr(bpy.data, k))
              for k in ("objects", "meshes", "hair_curves", "volumes", "materials", "particles", "images")}
    return {"objects": objects, "blocks": blocks,
            "selected": sorted(o.name for o in vl.objects if o.select_get()),
            "active": vl.objects.active.name if vl.objects.active else None,
            "frame": bpy.context.scene.frame_current, "files": files_under(folder)}


def same_state(before, after):
    """The keys that differ ([] when the scene is as it was)."""
    return [k for k in before if before[k] != after[k]]


def render(scene, path):
    """Renders the scene to `path`; the pixels (h, w, 4)."""
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    px = np.array(img.pixels[:], dtype=np.float32).reshape(img.size[1], img.size[0], 4)
    bpy.data.images.remove(img)
    return px


def save_sheet(shots, path):
    """Before | after, side by side with a white gap."""
    gap = np.ones((shots[0].shape[0], 6, 4), np.float32)
    pair = np.concatenate([shots[0], gap, shots[1]], axis=1)
    sheet = bpy.data.images.new(os.path.basename(path), pair.shape[1], pair.shape[0])
    sheet.pixels[:] = pair.ravel()
    sheet.filepath_raw = path
    sheet.file_format = "PNG"
    sheet.save()
    bpy.data.images.remove(sheet)
    check(os.path.exists(path), f"wrote {path}")


def setup_render(scene, size, samples):
    """Cycles on the CPU, a sun and a dark world, and a camera (returned)."""
    cam_data = bpy.data.cameras.new("cam")
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 4.0
    sun.rotation_euler = (0.9, 0.2, 0.6)
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("w")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.05, 0.07, 1)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    return cam


def pump(run, until, timeout=300.0):
    """Hands timer ticks to a run, as Blender's event loop does every
    0.25 s, until `until(run)` holds or the run ends; the last state."""
    import time

    t0 = time.time()
    state = {"RUNNING_MODAL"}
    while not until(run) and "RUNNING_MODAL" in state:
        if time.time() - t0 > timeout:
            raise SystemExit(f"FAILED: the run did not get there in {timeout:.0f} s")
        time.sleep(0.05)
        state = run.event("TIMER", "NOTHING")
    return state
