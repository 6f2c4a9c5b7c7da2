"""The panels: Stylize smoke in the Physics tab of a gas domain, Stylize
hair in the Object tab of hair."""

import bpy

from . import hair_io, volume_io
from .operators import NST3D_OT_stylize_hair, NST3D_OT_stylize_smoke


def _status(layout, s):
    if s.message:
        text = s.message[:60]
        if s.message not in ("done", "") and not s.message.startswith("cancel"):
            text += " (Esc cancels)"
        layout.prop(s, "progress", text=text)


class NST3D_PT_smoke(bpy.types.Panel):
    bl_label = "Stylize smoke (nst3d)"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "physics"

    @classmethod
    def poll(cls, context):
        return volume_io.domain(context.object) is not None

    def draw(self, context):
        layout, s = self.layout, context.object.nst3d
        layout.prop(s, "model")
        optimise = not s.model
        col = layout.column()
        col.active = optimise
        col.prop(s, "style")
        col.prop(s, "style_b")
        sub = col.column()
        sub.active = bool(s.style_b)
        sub.prop(s, "style_map")
        col.prop(s, "mode")
        layout.prop(s, "strength")
        row = layout.row(align=True)
        row.prop(s, "frame_start")
        row.prop(s, "frame_end")
        col = layout.column()
        col.active = optimise
        col.prop(s, "use_scene_camera")
        sub = col.column()
        sub.active = optimise and not s.use_scene_camera
        sub.prop(s, "cameras")
        col.prop(s, "iters")
        col.prop(s, "color")
        layout.prop(s, "output_dir")
        _status(layout, s)
        layout.operator(NST3D_OT_stylize_smoke.bl_idname, icon="BRUSH_DATA")


class NST3D_PT_hair(bpy.types.Panel):
    bl_label = "Stylize hair (nst3d)"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return hair_io.hair_curves(context.object) or hair_io.hair_particles(context.object) is not None

    def draw(self, context):
        layout, s = self.layout, context.object.nst3d
        layout.prop(s, "style")
        layout.prop(s, "style_b")
        sub = layout.row()
        sub.active = bool(s.style_b)
        sub.prop(s, "hair_map")
        layout.prop(s, "preset")
        layout.prop(s, "hair_iters")
        layout.prop(s, "render_size")
        row = layout.row()
        row.active = hair_io.hair_curves(context.object)  # particle hair keeps no colour
        row.prop(s, "color")
        _status(layout, s)
        layout.operator(NST3D_OT_stylize_hair.bl_idname, icon="BRUSH_DATA")


classes = (NST3D_PT_smoke, NST3D_PT_hair)
