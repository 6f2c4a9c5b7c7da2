"""The two operators, Stylize smoke and Stylize hair, each with its task:
what a run reads from the scene, computes, and commits or rolls back
(jobs.py runs it)."""

import json
import os
import shutil
import tempfile

import bpy

from . import hair_io, volume_io
from .jobs import JobOperator
from .props import nst3d_package


def _painting(s, needed=True):
    style = bpy.path.abspath(s.style) if s.style else ""
    if needed and not os.path.isfile(style):
        raise RuntimeError(f"choose a painting (not found: {style or 'none'})")
    return style or None


def _settings_of(name):
    # By name, not context.object: while a job runs the user may select another.
    obj = bpy.data.objects.get(name)
    return obj.nst3d if obj is not None else None


def _make_dirs(path):
    """Creates `path`; returns the topmost folder it created, else None."""
    top, probe = None, os.path.abspath(path)
    while not os.path.exists(probe):
        top, probe = probe, os.path.dirname(probe)
    os.makedirs(path, exist_ok=True)
    return top


class SmokeTask:
    """Stylizes a gas domain's cached frames into a folder of its own
    (a staging folder inside it until the run ends, so a cancelled run
    leaves an earlier result untouched) and loads them as a Volume object."""

    def __init__(self, context):
        obj = context.object
        ds = volume_io.domain(obj)
        if ds is None:
            raise RuntimeError("select a smoke (gas) domain")
        nst3d = nst3d_package()
        self.name, s = obj.name, obj.nst3d
        pattern, present = volume_io.cache_frames(ds)
        self.frames = [f for f in range(s.frame_start, s.frame_end + 1) if f in present]
        if not self.frames:
            raise RuntimeError(f"no cached frame in {s.frame_start}-{s.frame_end} (cached: {present[:1]}..{present[-1:]})")
        model = bpy.path.abspath(s.model) if s.model else None
        if model is None:
            opts = dict(mode=s.mode, cameras=s.cameras, iters=s.iters)
        elif not os.path.isfile(model):
            raise RuntimeError(f"model not found: {model}")
        elif s.color:
            raise RuntimeError("Colour needs the optimisation, not a model: clear Model or turn Colour off")
        else:
            opts = dict(model=model)
        style = _painting(s, needed=model is None)
        second = bpy.path.abspath(s.style_b) if s.style_b else ""
        if second:
            if model is not None:
                raise RuntimeError("Two paintings need the optimisation: clear Second painting, or clear Model")
            if not os.path.isfile(second):
                raise RuntimeError(f"second painting not found: {second}")
            style = [style, second]
            opts["style_map"] = s.style_map or "@height"
        self.color = bool(s.color)
        if self.color:
            opts.update(color=True, color_grid=volume_io.COLOR_GRID)
        camera = volume_io.scene_camera(context.scene, obj, self.frames) if s.use_scene_camera and not model else None
        self.out_dir = bpy.path.abspath(s.output_dir) if s.output_dir else os.path.dirname(pattern) + "_nst3d"
        self._made, self.staging = None, None
        try:
            self._made = _make_dirs(self.out_dir)
            self.staging = tempfile.mkdtemp(prefix=".nst3d-run-", dir=self.out_dir)
            if camera is not None:
                opts.pop("cameras")
                opts["camera_file"] = os.path.join(self.staging, "camera.json")
                with open(opts["camera_file"], "w") as f:
                    json.dump(camera, f)
        except OSError as e:
            self.rollback()
            raise RuntimeError(f"cannot write into {self.out_dir}: {e.strerror or e}") from e
        staged = os.path.join(self.staging, "fluid_data_####.vdb")
        opts.update(style=style, strength=s.strength)
        if len(self.frames) == 1:
            f = self.frames[0]
            self._call = lambda progress: nst3d.stylize_vdb(
                volume_io.frame(pattern, f), volume_io.frame(staged, f), progress=progress, **opts)
        else:
            spec = ",".join(str(f) for f in self.frames)
            self._call = lambda progress: nst3d.stylize_vdb(pattern, staged, frames=spec, progress=progress, **opts)

    def settings(self):
        return _settings_of(self.name)

    def work(self, progress):
        return self._call(progress)

    def commit(self, result):
        for f in self.frames:
            name = volume_io.frame("fluid_data_####.vdb", f)
            os.replace(os.path.join(self.staging, name), os.path.join(self.out_dir, name))
        shutil.rmtree(self.staging, ignore_errors=True)
        self._made = None
        domain = bpy.data.objects[self.name]
        out = os.path.join(self.out_dir, "fluid_data_####.vdb")
        vobj = volume_io.load_volume(domain, out, self.frames, domain.name + "_nst3d")
        if self.color:
            vobj.data.materials.append(volume_io.color_material(domain.name + "_nst3d"))
        return f"stylized {len(self.frames)} frame(s) into {self.out_dir}; loaded {vobj.name}"

    def rollback(self, scene=True):
        # The scene is untouched until commit; the files go.
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
        if self._made is not None:
            shutil.rmtree(self._made, ignore_errors=True)


class HairTask:
    """Stylizes the strands of a hair Curves object in place, or of a mesh's
    hair particle system through a temporary Curves object."""

    def __init__(self, context):
        obj = context.object
        self.name, s = obj.name, obj.nst3d
        nst3d = nst3d_package()
        style = _painting(s)
        self.particles, self.temp = hair_io.hair_particles(obj) is not None, None
        if self.particles:
            obj = hair_io.curves_from_particles(context, obj)
            self.temp = obj.name
        elif not hair_io.hair_curves(obj):
            raise RuntimeError("select a hair Curves object or a mesh with hair particles")
        try:
            self.curves = obj.name
            points, counts = hair_io.read_strands(obj.data)
            if len(points) == 0:
                raise RuntimeError(f"{obj.name} has no strands")
            # Blender is z-up: the cameras circle z and the result stays in
            # the object's axes.
            opts = dict(preset=s.preset, iters=s.hair_iters or None, render_size=s.render_size or None, up="z",
                        mesh=hair_io.read_surface(obj))
            second = bpy.path.abspath(s.style_b) if s.style_b else ""
            if second:
                if not os.path.isfile(second):
                    raise RuntimeError(f"second painting not found: {second}")
                style = [style, second]
                name = s.hair_map or "@height"
                opts["style_map"] = name if name.startswith("@") else hair_io.read_map(obj.data, name)
            # Particle hair has nowhere to keep a colour.
            self.color = bool(s.color) and not self.particles
            if self.color:
                opts.update(color=True, colors=hair_io.read_colors(obj.data))
        except Exception:
            self.rollback()
            raise
        self._call = lambda progress: nst3d.stylize_groom(points, counts, style, progress=progress, **opts)

    def settings(self):
        return _settings_of(self.name)

    def work(self, progress):
        return self._call(progress)

    def commit(self, result):
        obj = bpy.data.objects[self.curves]
        points, colors = result if self.color else (result, None)
        hair_io.write_strands(obj, points, colors)
        n = len(obj.data.curves)
        if self.particles:
            hair_io.particles_from_curves(bpy.context, obj)
            self.temp = None
            return f"stylized {n} strands of {self.name}'s hair particle system"
        return f"stylized {n} strands of {obj.name}"

    def rollback(self, scene=True):
        # Only the temporary Curves object of particle hair was added.
        obj = bpy.data.objects.get(self.temp) if scene and self.temp else None
        if obj is not None:
            hair_io.remove_curves(obj)
        self.temp = None


class NST3D_OT_stylize_smoke(JobOperator, bpy.types.Operator):
    """Stylize the domain's OpenVDB cache with a painting (or a trained model) and load the result as a Volume object.
    Esc cancels"""

    bl_idname = "nst3d.stylize_smoke"
    bl_label = "Stylize smoke"
    bl_options = {"REGISTER"}
    task_class = SmokeTask

    @classmethod
    def poll(cls, context):
        return volume_io.domain(context.object) is not None


class NST3D_OT_stylize_hair(JobOperator, bpy.types.Operator):
    """Stylize the strands of this hair (a Curves object, or a mesh's hair particle system) with a painting, in place.
    Esc cancels"""

    bl_idname = "nst3d.stylize_hair"
    bl_label = "Stylize hair"
    bl_options = {"REGISTER", "UNDO"}
    task_class = HairTask

    @classmethod
    def poll(cls, context):
        return hair_io.hair_curves(context.object) or hair_io.hair_particles(context.object) is not None


classes = (NST3D_OT_stylize_smoke, NST3D_OT_stylize_hair)
