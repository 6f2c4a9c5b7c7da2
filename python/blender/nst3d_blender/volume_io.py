"""Smoke in and out of Blender: a gas domain's OpenVDB cache, the stylized
frames loaded as a Volume object with a material that reads their colour,
and the scene camera written as an nst3d camera file."""

import os

import bpy
from mathutils import Matrix, Vector

# Blender's Principled Volume reads the colour grid by this name.
COLOR_GRID = "color"


def domain(obj):
    """The fluid domain settings of a gas domain, else None."""
    if obj is None:
        return None
    for m in obj.modifiers:
        if m.type == "FLUID" and m.fluid_type == "DOMAIN" and m.domain_settings.domain_type == "GAS":
            return m.domain_settings
    return None


def cache_frames(ds):
    """(pattern, frame numbers present) of a domain's OpenVDB cache."""
    data = os.path.join(bpy.path.abspath(ds.cache_directory), "data")
    if ds.cache_data_format != "OPENVDB":
        raise RuntimeError("the domain's cache is not OpenVDB (Cache > Format: OpenVDB)")
    if not os.path.isdir(data):
        raise RuntimeError(f"no baked cache in {data}: bake the domain first")
    present = sorted(int(f[11:15]) for f in os.listdir(data) if f.startswith("fluid_data_") and f.endswith(".vdb"))
    return os.path.join(data, "fluid_data_####.vdb"), present


def frame(pattern, f):
    return pattern.replace("####", f"{f:04d}")


def grid_to_world(domain_obj):
    """The matrix that places a domain's cache in the scene. Mantaflow writes
    its grids in the domain's object space with index (0, 0, 0) at the
    domain's lower corner: the domain's matrix moved to that corner."""
    corner = Vector([min(c[i] for c in domain_obj.bound_box) for i in range(3)])
    return domain_obj.matrix_world @ Matrix.Translation(corner)


def load_volume(domain_obj, pattern, frames, name):
    """A Volume object reading the frames `pattern` holds, placed as Blender
    places the domain's own cache, linked beside the domain."""
    vol = bpy.data.volumes.new(name)
    vol.filepath = frame(pattern, frames[0])
    if len(frames) > 1:
        vol.is_sequence = True
        vol.frame_start = frames[0]
        vol.frame_duration = frames[-1] - frames[0] + 1
    obj = bpy.data.objects.new(name, vol)
    obj.matrix_world = grid_to_world(domain_obj)
    cols = domain_obj.users_collection or [bpy.context.scene.collection]
    cols[0].objects.link(obj)
    return obj


def color_material(name):
    """A Principled Volume reading the stylized colour grid (`COLOR_GRID`)
    as its colour, so a Cycles or EEVEE render shows the painting's palette."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    for n in [n for n in nodes if n.type != "OUTPUT_MATERIAL"]:
        nodes.remove(n)
    pv = nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color Attribute"].default_value = COLOR_GRID
    pv.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    mat.node_tree.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    return mat


def _film(scene, cam):
    """Resolution and nst3d's lens keys of a Blender camera: Houdini's
    horizontal aperture, which Blender's sensor is when it fits the width."""
    r = scene.render
    resx = max(1, round(r.resolution_x * r.resolution_percentage / 100))
    resy = max(1, round(r.resolution_y * r.resolution_percentage / 100))
    aspect = resx * r.pixel_aspect_x / (resy * r.pixel_aspect_y)
    fit = cam.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspect >= 1 else "VERTICAL"
    keys = {"resx": resx, "resy": resy}
    if r.pixel_aspect_x != r.pixel_aspect_y:
        keys["pixel_aspect"] = r.pixel_aspect_x / r.pixel_aspect_y
    if cam.type == "ORTHO":
        # ortho_scale spans the fitted side.
        keys.update(projection="orthographic",
                    ortho_width=cam.ortho_scale if fit == "HORIZONTAL" else cam.ortho_scale * aspect)
    elif cam.type == "PERSP":
        sensor = cam.sensor_width if fit == "HORIZONTAL" or cam.sensor_fit == "AUTO" else cam.sensor_height
        keys.update(projection="perspective", focal=cam.lens,
                    aperture=sensor if fit == "HORIZONTAL" else sensor * aspect)
    else:
        raise RuntimeError(f"the scene camera is {cam.type.lower()}: nst3d takes a perspective or orthographic one")
    return keys


def _pose(cam_obj, world_to_grid):
    """Position, a point looked at and up, in the cache's space."""
    m = world_to_grid @ cam_obj.matrix_world
    eye = m @ Vector((0.0, 0.0, 0.0))
    ahead = m @ Vector((0.0, 0.0, -1.0))
    up = m.to_3x3() @ Vector((0.0, 1.0, 0.0))
    return {"position": list(eye), "look_at": list(ahead), "up": list(up)}


def scene_camera(scene, domain_obj, frames):
    """The scene camera as an nst3d camera file (a dict for JSON), in the
    space of the domain's cache: one camera, or one key per frame when it
    moves. Steps the scene through `frames` and back."""
    cam_obj = scene.camera
    if cam_obj is None or cam_obj.type != "CAMERA":
        raise RuntimeError("the scene has no camera (Scene > Camera)")
    current = scene.frame_current
    keys = {}
    try:
        for f in frames:
            if len(frames) > 1:
                scene.frame_set(f)
            else:
                bpy.context.view_layer.update()  # matrix_world after edits
            world_to_grid = grid_to_world(domain_obj).inverted()
            key = {**_pose(cam_obj, world_to_grid), **_film(scene, cam_obj.data)}
            if "ortho_width" in key:
                key["ortho_width"] *= sum(world_to_grid.to_scale()) / 3
            keys[str(f)] = key
    finally:
        if scene.frame_current != current:
            scene.frame_set(current)
    first = next(iter(keys.values()))
    if all(k == first for k in keys.values()):
        return first
    return {"frames": keys}
