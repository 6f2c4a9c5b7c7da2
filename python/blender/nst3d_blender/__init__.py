"""nst3d for Blender: stylize a smoke domain's OpenVDB cache, or a hair
Curves object, with a painting, from the Physics / Object properties.

The work is done by the ``nst3d`` Python package (the same Rust library as
the ``nst3d`` command line), which must be importable by Blender's Python:
install the wheel into it (``<blender python> -m pip install nst3d-*.whl``)
or point the add-on preferences at a folder that holds the package.

- **Stylize smoke** (Physics tab of a Fluid domain with an OpenVDB cache):
  the cache's ``fluid_data_####.vdb`` frames are stylized into a new cache
  folder (every other grid kept) and loaded as a Volume object beside the
  domain, at the domain's place.
- **Stylize hair** (Object tab of a hair Curves object, or of a mesh with a
  hair particle system): the strands are stylized and written back, with
  the surface mesh (if any) as the collision head. Particle hair goes
  through Blender's own conversions (particles → Curves → particles).
  With **Colour** on a Curves object the strands' colour is stylized too,
  written as an ``nst3d_color`` point attribute and read by a Principled BSDF
  material the object gets (particle hair has nowhere to keep it).

In the UI the job runs in a background thread with a progress bar in the
panel and the window's progress cursor; ``bpy.app.background`` runs it in
place (headless tests, farm scripts).
"""

import os
import sys
import threading

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

bl_info = {
    "name": "nst3d: stylize smoke and hair with a painting",
    "author": "nst3d",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Physics (smoke domain), Properties > Object (hair curves)",
    "description": "Neural style transfer for smoke volumes and hair grooms (nst3d)",
    "category": "Physics",
}


def _nst3d():
    """The nst3d package, found on sys.path or in the add-on's preferences."""
    prefs = bpy.context.preferences.addons.get(__name__)
    extra = prefs.preferences.package_path if prefs else ""
    if extra and bpy.path.abspath(extra) not in sys.path:
        sys.path.append(bpy.path.abspath(extra))
    try:
        import nst3d
    except ImportError as e:
        raise RuntimeError(
            "the nst3d Python package is not importable by Blender's Python "
            "(install its wheel into Blender's Python, or set its folder in the add-on preferences)"
        ) from e
    return nst3d


class Nst3dPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    package_path: StringProperty(
        name="nst3d package folder",
        description="A folder holding the nst3d package, if Blender's Python does not have it",
        subtype="DIR_PATH",
    )

    def draw(self, context):
        self.layout.prop(self, "package_path")


_MODES = [("velocity", "Velocity", "Move the smoke (the look follows the painting's strokes)"),
          ("density", "Density", "Scale the smoke in place (keeps its silhouette)")]
_STRENGTHS = [("subtle", "Subtle", ""), ("default", "Default", ""), ("strong", "Strong", "")]
_PRESETS = [("short-hair", "Short hair", ""), ("short-hair-360", "Short hair 360", ""),
            ("long-hair", "Long hair", ""), ("cat", "Cat fur", ""), ("fur-ball", "Fur ball", ""),
            ("grass", "Grass", "")]


class Nst3dSettings(bpy.types.PropertyGroup):
    style: StringProperty(name="Painting", subtype="FILE_PATH", description="The style painting (PNG or JPEG)")
    mode: EnumProperty(name="Mode", items=_MODES, default="velocity")
    strength: EnumProperty(name="Strength", items=_STRENGTHS, default="default")
    frame_start: IntProperty(name="Start", default=1, min=0)
    frame_end: IntProperty(name="End", default=1, min=0)
    cameras: StringProperty(name="Cameras", default="front",
                            description="front, omniview:N (all around) or ring:N[:ELEV]")
    iters: IntProperty(name="Iterations", default=20, min=1, description="Iterations per octave")
    color: BoolProperty(name="Colour", default=False,
                        description="Stylize the colour too: smoke gets a 'color' grid and hair Curves an "
                                    "'nst3d_color' point attribute, each read by a material the add-on gives the result")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", default="",
                               description="New cache folder (default: the cache's data folder + _nst3d)")
    preset: EnumProperty(name="Preset", items=_PRESETS, default="short-hair")
    hair_iters: IntProperty(name="Iterations", default=0, min=0,
                            description="Iterations over the three scales (0: the preset's)")
    render_size: IntProperty(name="Render size", default=0, min=0,
                             description="Square render size in pixels (0: the preset's)")
    progress: FloatProperty(name="Progress", default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    message: StringProperty(name="Status", default="")


def _domain(obj):
    """The fluid domain settings of a gas domain, else None."""
    if obj is None:
        return None
    for m in obj.modifiers:
        if m.type == "FLUID" and m.fluid_type == "DOMAIN" and m.domain_settings.domain_type == "GAS":
            return m.domain_settings
    return None


def _cache_frames(ds):
    """(pattern, out folder, frame numbers present) of a domain's OpenVDB cache."""
    data = os.path.join(bpy.path.abspath(ds.cache_directory), "data")
    if ds.cache_data_format != "OPENVDB":
        raise RuntimeError("the domain's cache is not OpenVDB (Cache > Format: OpenVDB)")
    if not os.path.isdir(data):
        raise RuntimeError(f"no baked cache in {data}: bake the domain first")
    present = sorted(int(f[11:15]) for f in os.listdir(data) if f.startswith("fluid_data_") and f.endswith(".vdb"))
    return os.path.join(data, "fluid_data_####.vdb"), present


class _Job:
    """A job in a background thread; the modal operator polls it."""

    def __init__(self, fn):
        self.done, self.total, self.message = 0, 0, ""
        self.result, self.error = None, None
        self.thread = threading.Thread(target=self._run, args=(fn,), daemon=True)

    def progress(self, done, total, message):
        self.done, self.total, self.message = done, total, message

    def _run(self, fn):
        try:
            self.result = fn(self.progress)
        except BaseException as e:  # reported in Blender's UI, never lost
            self.error = e


class _Nst3dOperator:
    """Runs `self.work(progress)` in place (background) or in a thread with a timer."""

    _job = None
    _timer = None

    def execute(self, context):
        try:
            work = self.prepare(context)
        except Exception as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        wm = context.window_manager
        if bpy.app.background:
            wm.progress_begin(0, 1)

            def progress(done, total, message):
                if total:
                    wm.progress_update(done / total)
                    print(f"nst3d: [{done}/{total}] {message}", flush=True)

            try:
                result = work(progress)
            except Exception as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
            finally:
                wm.progress_end()
            return self.finish(context, result)
        self._job = _Job(work)
        self._job.thread.start()
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 1)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job, s = self._job, self.settings(context)
        if job.total:
            s.progress = job.done / job.total
            s.message = job.message
            context.window_manager.progress_update(s.progress)
        for area in context.screen.areas:
            area.tag_redraw()
        if job.thread.is_alive():
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        if job.error is not None:
            s.message = f"failed: {job.error}"
            self.report({"ERROR"}, str(job.error))
            return {"CANCELLED"}
        s.message = "done"
        return self.finish(context, job.result)


class NST3D_OT_stylize_smoke(_Nst3dOperator, bpy.types.Operator):
    """Stylize the domain's OpenVDB cache with a painting and load the result as a Volume object"""

    bl_idname = "nst3d.stylize_smoke"
    bl_label = "Stylize smoke"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return _domain(context.object) is not None

    def settings(self, context):
        # Not context.object: while the job runs the user may select another.
        return bpy.data.objects[self._settings_of].nst3d

    def prepare(self, context):
        nst3d = _nst3d()
        obj = context.object
        self._settings_of = obj.name
        s = obj.nst3d
        ds = _domain(obj)
        pattern, present = _cache_frames(ds)
        frames = [f for f in range(s.frame_start, s.frame_end + 1) if f in present]
        if not frames:
            raise RuntimeError(f"no cached frame in {s.frame_start}-{s.frame_end} (cached: {present[:1]}..{present[-1:]})")
        style = bpy.path.abspath(s.style)
        if not os.path.isfile(style):
            raise RuntimeError(f"choose a painting (not found: {style or 'none'})")
        out_dir = bpy.path.abspath(s.output_dir) if s.output_dir else os.path.dirname(pattern) + "_nst3d"
        os.makedirs(out_dir, exist_ok=True)
        out = os.path.join(out_dir, "fluid_data_####.vdb")
        self._obj_name, self._frames, self._out = obj.name, frames, out
        opts = dict(mode=s.mode, strength=s.strength, cameras=s.cameras, iters=s.iters)
        self._color = bool(s.color)
        if self._color:
            # Blender's Principled Volume reads the grid by this name.
            opts.update(color=True, color_grid=COLOR_GRID)

        def work(progress):
            if len(frames) == 1:
                f = frames[0]
                return nst3d.stylize_vdb(_frame(pattern, f), _frame(out, f), style, progress=progress, **opts)
            spec = ",".join(str(f) for f in frames)
            return nst3d.stylize_vdb(pattern, out, style, frames=spec, progress=progress, **opts)

        return work

    def finish(self, context, result):
        domain = bpy.data.objects[self._obj_name]
        vobj = load_volume(domain, self._out, self._frames, domain.name + "_nst3d")
        if self._color:
            vobj.data.materials.append(color_material(domain.name + "_nst3d"))
        self.report({"INFO"}, f"stylized {len(self._frames)} frame(s) into {os.path.dirname(self._out)}; loaded {vobj.name}")
        return {"FINISHED"}


COLOR_GRID = "color"


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


# Not "color": Blender 3.4's Cycles reads a Curves point attribute of that
# name as black through an Attribute node (measured); any other name works.
HAIR_COLOR = "nst3d_color"


def hair_color_material(name):
    """A Principled BSDF whose base colour is the stylized point attribute
    (`HAIR_COLOR`), so a Cycles or EEVEE render shows the painting's palette
    in the hair. (A Principled Hair BSDF in direct colouring reads the same
    attribute, but turns these light colours into dark hair under the
    test's light: a starting point, not the look.)"""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    for n in [n for n in nodes if n.type != "OUTPUT_MATERIAL"]:
        nodes.remove(n)
    hair = nodes.new("ShaderNodeBsdfPrincipled")
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = HAIR_COLOR
    mat.node_tree.links.new(attr.outputs["Color"], hair.inputs["Base Color"])
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    mat.node_tree.links.new(hair.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _frame(pattern, f):
    return pattern.replace("####", f"{f:04d}")


def load_volume(domain, pattern, frames, name):
    """A Volume object reading the frames `pattern` holds, placed as Blender
    places the domain's own cache, linked beside the domain. Mantaflow writes
    its grids in the domain's object space with index (0, 0, 0) at the
    domain's lower corner, so the object gets the domain's matrix moved to
    that corner."""
    vol = bpy.data.volumes.new(name)
    vol.filepath = _frame(pattern, frames[0])
    if len(frames) > 1:
        vol.is_sequence = True
        vol.frame_start = frames[0]
        vol.frame_duration = frames[-1] - frames[0] + 1
    obj = bpy.data.objects.new(name, vol)
    from mathutils import Matrix, Vector

    corner = Vector([min(c[i] for c in domain.bound_box) for i in range(3)])
    obj.matrix_world = domain.matrix_world @ Matrix.Translation(corner)
    cols = domain.users_collection or [bpy.context.scene.collection]
    cols[0].objects.link(obj)
    return obj


def _hair_curves(obj):
    return obj is not None and obj.type == "CURVES"


def _hair_particles(obj):
    """The active hair particle system of a mesh, else None."""
    if obj is None or obj.type != "MESH":
        return None
    ps = obj.particle_systems.active
    return ps if ps is not None and ps.settings.type == "HAIR" else None


def _curves_from_particles(context, mesh_obj):
    """A temporary hair Curves object holding the mesh's particle hair
    (Blender's own conversion), with the mesh as its surface."""
    before = set(bpy.data.objects)
    with context.temp_override(object=mesh_obj, active_object=mesh_obj, selected_objects=[mesh_obj]):
        bpy.ops.curves.convert_from_particle_system()
    new = [o for o in bpy.data.objects if o not in before and o.type == "CURVES"]
    if not new:
        raise RuntimeError(f"Blender could not convert the hair of {mesh_obj.name} to curves")
    curves = new[0]
    curves.data.surface = mesh_obj
    return curves


def _particles_from_curves(context, curves_obj):
    """Writes a Curves object back into its surface's hair particle system
    (Blender's own conversion) and removes the Curves object."""
    with context.temp_override(object=curves_obj, active_object=curves_obj, selected_objects=[curves_obj]):
        r = bpy.ops.curves.convert_to_particle_system()
    if r != {"FINISHED"}:
        raise RuntimeError(f"Blender could not write the strands back into the particle system ({r})")
    data = curves_obj.data
    bpy.data.objects.remove(curves_obj)
    bpy.data.hair_curves.remove(data)


class NST3D_OT_stylize_hair(_Nst3dOperator, bpy.types.Operator):
    """Stylize the strands of this hair (a Curves object, or a mesh's hair particle system) with a painting, in place"""

    bl_idname = "nst3d.stylize_hair"
    bl_label = "Stylize hair"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _hair_curves(context.object) or _hair_particles(context.object) is not None

    def settings(self, context):
        # Not context.object: while the job runs the user may select another.
        return bpy.data.objects[self._settings_of].nst3d

    def prepare(self, context):
        import numpy as np

        nst3d = _nst3d()
        self._settings_of = context.object.name
        s = context.object.nst3d
        # Particle hair goes through a temporary Curves object and back.
        self._particles = None
        obj = context.object
        if _hair_particles(obj) is not None:
            self._particles = obj.name
            obj = _curves_from_particles(context, obj)
        # A failed preparation (no painting, no strands, ...) removes the
        # temporary Curves object here; after a job, finish() does.
        prepared = False
        try:
            style = bpy.path.abspath(s.style)
            if not os.path.isfile(style):
                raise RuntimeError(f"choose a painting (not found: {style or 'none'})")
            curves = obj.data
            n = len(curves.points)
            if n == 0:
                raise RuntimeError(f"{obj.name} has no strands")
            points = np.empty(n * 3, dtype=np.float32)
            curves.attributes["position"].data.foreach_get("vector", points)
            counts = np.array([c.points_length for c in curves.curves], dtype=np.int64)
            mesh = None
            surface = curves.surface
            if surface is not None and surface.type == "MESH":
                m = surface.data
                verts = np.empty(len(m.vertices) * 3, dtype=np.float32)
                m.vertices.foreach_get("co", verts)
                m.calc_loop_triangles()
                tris = np.empty(len(m.loop_triangles) * 3, dtype=np.int64)
                m.loop_triangles.foreach_get("vertices", tris)
                # The curves live in the object's space, the surface in its own.
                to_curves = obj.matrix_world.inverted() @ surface.matrix_world
                v = verts.reshape(-1, 3)
                rot = np.array(to_curves.to_3x3(), dtype=np.float32)
                v = v @ rot.T + np.array(to_curves.translation, dtype=np.float32)
                mesh = (v.astype(np.float32), tris.reshape(-1, 3))
            self._obj_name = obj.name
            # Blender is z-up: the cameras circle z and the result stays in
            # the object's axes.
            opts = dict(preset=s.preset, iters=s.hair_iters or None, render_size=s.render_size or None, up="z")
            # Colour lives in a point attribute of a Curves
            # object; particle hair has nowhere to keep it.
            self._color = bool(s.color) and self._particles is None
            if self._color:
                opts["color"] = True
                attr = curves.attributes.get(HAIR_COLOR)
                if attr is not None and attr.domain == "POINT" and attr.data_type in ("FLOAT_COLOR", "BYTE_COLOR"):
                    rgba = np.empty(n * 4, dtype=np.float32)
                    attr.data.foreach_get("color", rgba)
                    opts["colors"] = rgba.reshape(-1, 4)[:, :3]

            def work(progress):
                return nst3d.stylize_groom(points.reshape(-1, 3), counts, style, mesh=mesh, progress=progress, **opts)

            prepared = True
        finally:
            if not prepared and self._particles is not None:
                data = obj.data
                bpy.data.objects.remove(obj)
                bpy.data.hair_curves.remove(data)
        return work

    def finish(self, context, result):
        obj = bpy.data.objects[self._obj_name]
        colors = None
        if self._color:
            result, colors = result
        obj.data.attributes["position"].data.foreach_set("vector", result.ravel())
        if colors is not None:
            import numpy as np

            attr = obj.data.attributes.get(HAIR_COLOR)
            if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_COLOR":
                if attr is not None:
                    obj.data.attributes.remove(attr)
                attr = obj.data.attributes.new(HAIR_COLOR, "FLOAT_COLOR", "POINT")
            rgba = np.concatenate([colors, np.ones((len(colors), 1), np.float32)], axis=1)
            attr.data.foreach_set("color", rgba.astype(np.float32).ravel())
            obj.data.materials.clear()
            obj.data.materials.append(hair_color_material(obj.name + "_nst3d"))
        obj.data.update_tag()
        n = len(obj.data.curves)
        if self._particles is not None:
            _particles_from_curves(context, obj)
            self.report({"INFO"}, f"stylized {n} strands of {self._particles}'s hair particle system")
        else:
            self.report({"INFO"}, f"stylized {n} strands of {obj.name}")
        return {"FINISHED"}


def _draw_common(layout, s, smoke):
    layout.prop(s, "style")
    if smoke:
        layout.prop(s, "mode")
        layout.prop(s, "strength")
        row = layout.row(align=True)
        row.prop(s, "frame_start")
        row.prop(s, "frame_end")
        layout.prop(s, "cameras")
        layout.prop(s, "iters")
        layout.prop(s, "color")
        layout.prop(s, "output_dir")
    else:
        layout.prop(s, "preset")
        layout.prop(s, "hair_iters")
        layout.prop(s, "render_size")
        layout.prop(s, "color")
    if s.message:
        layout.prop(s, "progress", text=s.message[:60])


class NST3D_PT_smoke(bpy.types.Panel):
    bl_label = "Stylize smoke (nst3d)"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "physics"

    @classmethod
    def poll(cls, context):
        return _domain(context.object) is not None

    def draw(self, context):
        _draw_common(self.layout, context.object.nst3d, smoke=True)
        self.layout.operator(NST3D_OT_stylize_smoke.bl_idname, icon="BRUSH_DATA")


class NST3D_PT_hair(bpy.types.Panel):
    bl_label = "Stylize hair (nst3d)"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return _hair_curves(context.object) or _hair_particles(context.object) is not None

    def draw(self, context):
        _draw_common(self.layout, context.object.nst3d, smoke=False)
        self.layout.operator(NST3D_OT_stylize_hair.bl_idname, icon="BRUSH_DATA")


_classes = (Nst3dPreferences, Nst3dSettings, NST3D_OT_stylize_smoke, NST3D_OT_stylize_hair, NST3D_PT_smoke, NST3D_PT_hair)


def register():
    for c in _classes:
        bpy.utils.register_class(c)
    bpy.types.Object.nst3d = PointerProperty(type=Nst3dSettings)


def unregister():
    del bpy.types.Object.nst3d
    for c in reversed(_classes):
        bpy.utils.unregister_class(c)
