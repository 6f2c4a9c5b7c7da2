"""Stylize smoke: for the scene camera with colour (Cycles before | after),
with a feed-forward model, and cancelled with Esc."""

import os
import time

import bpy
import numpy as np
from bpy_extras.object_utils import world_to_camera_view

from .common import check, pump, render, same_state, save_sheet, scene_state


def _project(cam, p):
    """Where nst3d's camera-file camera puts point `p` (the cache's space),
    in Blender's camera-view coordinates (x, y in [0, 1] across the frame)."""
    eye, at, up = (np.array(cam[k], float) for k in ("position", "look_at", "up"))
    f = (at - eye) / np.linalg.norm(at - eye)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.array(p, float) - eye
    x, y, z = d @ r, d @ u, d @ f
    half_w = cam["aperture"] / 2 / cam["focal"]  # tan of half the horizontal view
    half_h = half_w * cam["resy"] / cam["resx"]
    return 0.5 + x / z / half_w / 2, 0.5 + y / z / half_h / 2


def scene_camera(addon, scene, domain, frame):
    """The camera file the add-on writes puts the domain's corners where
    Blender's own projection puts them."""
    cam = addon.volume_io.scene_camera(scene, domain, [frame])
    to_grid = addon.volume_io.grid_to_world(domain).inverted()
    worst = 0.0
    for corner in domain.bound_box:
        world = domain.matrix_world @ type(scene.camera.location)(corner)
        want = world_to_camera_view(scene, scene.camera, world)
        got = _project(cam, to_grid @ world)
        worst = max(worst, abs(got[0] - want.x), abs(got[1] - want.y))
    check(worst < 1e-4, f"the scene camera's file frames the domain as Blender does (worst {worst:.1e} of the frame)")


def stylize(addon, domain, out, cache, style, frame, iters, legacy):
    """Stylize smoke for the scene camera with colour; checks the result."""
    s = domain.nst3d
    s.style, s.frame_start, s.frame_end, s.iters, s.mode = style, frame, frame, iters, "velocity"
    s.color = True  # the colour grid, wired into the volume's material
    s.use_scene_camera = True
    s.output_dir = os.path.join(out, "styled")
    t0 = time.time()
    with bpy.context.temp_override(object=domain, active_object=domain, selected_objects=[domain]):
        check(bpy.ops.nst3d.stylize_smoke.poll(), "the operator is offered on the smoke domain")
        result = bpy.ops.nst3d.stylize_smoke()
    check(result == {"FINISHED"}, f"Stylize smoke for the scene camera finished ({result}, {time.time() - t0:.1f} s)")
    styled = bpy.data.objects.get(domain.name + "_nst3d")
    check(styled is not None and styled.type == "VOLUME", "a Volume object is loaded beside the domain")
    vol = styled.data
    vol.grids.load()
    names = [g.name for g in vol.grids]
    check(vol.grids.is_loaded and "density" in names, f"Blender reads the stylized file's density ({names})")
    check("color" in names, f"and the stylized colour grid ({names})")
    check(len(vol.materials) == 1, "the add-on gave the stylized volume a material")
    pv = next(n for n in vol.materials[0].node_tree.nodes if n.type == "PRINCIPLED_VOLUME")
    check(pv.inputs["Color Attribute"].default_value == "color", "whose Principled Volume reads the colour grid")
    check(not [f for f in os.listdir(s.output_dir) if f.startswith(".")], "no staging folder is left")
    if legacy:
        _mass(cache, s.output_dir, frame)
    return styled, pv


def _mass(cache, styled, frame):
    """With Debian's OpenVDB (the library Blender 3.4 links): the stylized
    grid is finite and keeps the smoke's mass."""
    import pyopenvdb

    def world_mass(path):
        g = pyopenvdb.read(path, "density")
        lo, hi = g.evalActiveVoxelBoundingBox()
        d = np.zeros(tuple(h - l + 1 for l, h in zip(lo, hi)), np.float32)
        g.copyToArray(d, ijk=lo)
        vs = g.transform.voxelSize()[0]
        return float(d.sum()) * vs**3, vs, d

    name = f"fluid_data_{frame:04d}.vdb"
    ma, va, _ = world_mass(os.path.join(cache, name))
    mb, vb, db = world_mass(os.path.join(styled, name))
    k = va / vb
    check(abs(k - round(k)) < 1e-6 and np.isfinite(db).all(), f"the stylized grid is finite, {round(k)}x finer than the cache")
    check(0.5 < mb / ma < 2.0, f"the smoke is moved, not lost or made (mass ratio {mb / ma:.3f})")


def pictures(addon, scene, domain, styled, pv_styled, frame, out, cache):
    """Cycles renders of the baked and the stylized frame from the scene
    camera; the before | after sheet."""
    before = addon.volume_io.load_volume(domain, os.path.join(cache, "fluid_data_####.vdb"), [frame], "original")
    mat = bpy.data.materials.new("smoke")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    pv = nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Density"].default_value = 8.0
    mat.node_tree.links.new(pv.outputs["Volume"], nodes["Material Output"].inputs["Volume"])
    before.data.materials.append(mat)
    # The add-on's own colour material, as dense as the grey one for the picture.
    pv_styled.inputs["Density"].default_value = pv.inputs["Density"].default_value
    shots = []
    for name, show, hide in (("before", before, styled), ("after", styled, before)):
        show.hide_render, hide.hide_render = False, True
        shots.append(render(scene, os.path.join(out, f"blender_{name}.png")))
        check(shots[-1][..., :3].max() > 0.2, f"the {name} render shows smoke")
    bg = shots[0][0, 0, :3]
    smoke = np.abs(shots[0][..., :3] - bg).mean()
    diff = np.abs(shots[0][..., :3] - shots[1][..., :3]).mean()
    check(diff > 0.1 * smoke, f"before and after renders differ ({diff / smoke:.0%} of the smoke's own contrast)")

    def chroma(px):
        """Mean channel spread (max - min) over the pixels that show smoke."""
        lit = np.abs(px[..., :3] - bg).max(axis=2) > 0.05
        spread = px[..., :3].max(axis=2) - px[..., :3].min(axis=2)
        return float(spread[lit].mean()) if lit.any() else 0.0

    c0, c1 = chroma(shots[0]), chroma(shots[1])
    check(c1 > 0.02 and c1 > 2 * c0, f"Cycles shows the stylized smoke in colour (channel spread {c1:.3f}, the original's {c0:.3f})")
    save_sheet(shots, os.path.join(out, "blender_smoke_before_after.png"))
    before.hide_render = styled.hide_render = True
    return bg


def _stylize_and_load(domain, what):
    """Runs Stylize smoke into the domain's output folder as set; checks that
    it finished and that Blender reads the result's density, then hides it."""
    s = domain.nst3d
    t0 = time.time()
    with bpy.context.temp_override(object=domain, active_object=domain, selected_objects=[domain]):
        result = bpy.ops.nst3d.stylize_smoke()
    check(result == {"FINISHED"}, f"Stylize smoke with {what} finished ({result}, {time.time() - t0:.1f} s)")
    obj = next(o for o in bpy.data.objects if o.type == "VOLUME" and o.data.filepath.startswith(s.output_dir))
    obj.data.grids.load()
    check(obj.data.grids.is_loaded and "density" in [g.name for g in obj.data.grids],
          f"Blender reads the density stylized with {what}")
    obj.hide_render = True


def model(addon, domain, out, model_path, frame):
    """Stylize smoke with a feed-forward model: no painting, one pass."""
    s = domain.nst3d
    s.style, s.color, s.model = "", False, model_path
    s.output_dir = os.path.join(out, "styled_model")
    _stylize_and_load(domain, "a feed-forward model")
    s.model = ""


def two_paintings(addon, domain, out, style, style_b, model_path, frame):
    """Two paintings on one frame, the second above mid-height (a style map),
    with colour (each half coloured by its painting, the colour grid wired
    into the material); a second painting with a model is one error line."""
    s = domain.nst3d
    s.style, s.style_b, s.style_map, s.color, s.model = style, style_b, "@height-split", True, ""
    s.iters, s.use_scene_camera, s.cameras = 2, False, "front"
    s.output_dir = os.path.join(out, "styled_map")
    _stylize_and_load(domain, "two paintings by a style map, in colour")
    obj = next(o for o in bpy.data.objects if o.type == "VOLUME" and o.data.filepath.startswith(s.output_dir))
    check(addon.volume_io.COLOR_GRID in [g.name for g in obj.data.grids] and len(obj.data.materials) == 1,
          "the two paintings' colour grid is loaded and wired into a material")
    s.color, s.model = False, model_path
    with bpy.context.temp_override(object=domain, active_object=domain, selected_objects=[domain]):
        try:
            result, message = bpy.ops.nst3d.stylize_smoke(), ""
        except RuntimeError as e:  # an operator's error report raises in background mode
            result, message = {"CANCELLED"}, str(e).strip()
    check(result == {"CANCELLED"} and "Two paintings" in message, f"a second painting with a model is one line: '{message}'")
    s.model, s.style_b = "", ""


def cancel(addon, domain, out, style, frame):
    """Esc while Stylize smoke runs: the run stops and the scene and the
    output folder (holding an earlier result) are as they were."""
    s = domain.nst3d
    s.style, s.color, s.model, s.iters = style, True, "", 15
    s.output_dir = os.path.join(out, "styled")
    before = scene_state(out)
    with bpy.context.temp_override(object=domain, active_object=domain, selected_objects=[domain]):
        run = addon.jobs.Run(addon.operators.SmokeTask(bpy.context))
    state = pump(run, lambda r: r.done >= 1)
    check(state == {"RUNNING_MODAL"} and run.thread.is_alive(), f"the smoke job runs in its thread ({run.done}/{run.total})")
    check(run.event("MOUSEMOVE", "NOTHING") == {"PASS_THROUGH"}, "other events pass through while it runs")
    t0 = time.time()
    check(run.event("ESC", "PRESS") == {"RUNNING_MODAL"}, "Esc is consumed by the running operator")
    check(run.event("ESC", "RELEASE") == {"RUNNING_MODAL"}, "and so is its release")
    state = pump(run, lambda r: False)
    check(state == {"CANCELLED"} and run.report[0] == {"WARNING"},
          f"Esc cancels Stylize smoke in {time.time() - t0:.1f} s ({state}, '{run.report[1]}')")
    changed = same_state(before, scene_state(out))
    check(not changed, f"the scene and the earlier result are as they were (changed: {changed})")


def bad_output(domain, out, style, frame):
    """An output folder that cannot be made: one line in Blender's report,
    nothing left behind."""
    s = domain.nst3d
    s.style, s.model, s.frame_start, s.frame_end = style, "", frame, frame
    blocker = os.path.join(out, "a_file")
    open(blocker, "w").close()
    s.output_dir = os.path.join(blocker, "styled")
    before = scene_state(out)
    with bpy.context.temp_override(object=domain, active_object=domain, selected_objects=[domain]):
        try:
            result, message = bpy.ops.nst3d.stylize_smoke(), ""
        except RuntimeError as e:  # an operator's error report raises in background mode
            result, message = {"CANCELLED"}, str(e).strip()
    check(result == {"CANCELLED"} and len(message.splitlines()) == 1 and "cannot write into" in message,
          f"an output folder that cannot be made is one line: '{message}'")
    check(not same_state(before, scene_state(out)), "and leaves the scene and the files as they were")
    os.remove(blocker)
