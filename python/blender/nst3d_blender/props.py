"""The add-on's settings: the per-object panel settings, the preferences,
and where the nst3d package comes from."""

import sys

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

# The add-on's module name: "nst3d_blender" as a legacy add-on,
# "bl_ext.<repository>.nst3d" as an extension. Preferences are keyed by it.
ADDON = __package__
# An extension brings the package in its wheel (and must leave sys.path alone).
EXTENSION = ADDON.startswith("bl_ext.")


def nst3d_package():
    """The nst3d package: the extension's bundled wheel, Blender's Python, or
    (legacy add-on) the folder set in the add-on's preferences."""
    addon = bpy.context.preferences.addons.get(ADDON)
    extra = addon.preferences.package_path if addon and addon.preferences and not EXTENSION else ""
    if extra and bpy.path.abspath(extra) not in sys.path:
        sys.path.append(bpy.path.abspath(extra))
    try:
        import nst3d
    except ImportError as e:
        raise RuntimeError(
            "the nst3d Python package is not importable by Blender's Python "
            "(install the nst3d extension, or its wheel into Blender's Python, "
            "or set its folder in the add-on preferences)"
        ) from e
    return nst3d


class Nst3dPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON
    package_path: StringProperty(
        name="nst3d package folder",
        description="A folder holding the nst3d package, if Blender's Python does not have it "
                    "(the extension brings its own)",
        subtype="DIR_PATH",
    )

    def draw(self, context):
        if EXTENSION:
            self.layout.label(text="The nst3d package comes with the extension.")
        else:
            self.layout.prop(self, "package_path")


_MODES = [("velocity", "Velocity", "Move the smoke (the look follows the painting's strokes)"),
          ("density", "Density", "Scale the smoke in place (keeps its silhouette)")]
_STRENGTHS = [("subtle", "Subtle", ""), ("default", "Default", ""), ("strong", "Strong", "")]
_PRESETS = [("short-hair", "Short hair", ""), ("short-hair-360", "Short hair 360", ""),
            ("long-hair", "Long hair", ""), ("cat", "Cat fur", ""), ("fur-ball", "Fur ball", ""),
            ("grass", "Grass", "")]


class Nst3dSettings(bpy.types.PropertyGroup):
    style: StringProperty(name="Painting", subtype="FILE_PATH", description="The style painting (PNG or JPEG)")
    style_b: StringProperty(name="Second painting", subtype="FILE_PATH", default="",
                            description="A second painting, placed by Style map (smoke) or Hair map (hair); "
                                        "empty: one painting everywhere")
    style_map: StringProperty(name="Style map", default="@height",
                              description="Where the second painting goes: a grid of the domain's cache such as "
                                          "temperature (0: the first painting, 1: the second), @height (bottom to top) or "
                                          "@height-split (a cut at mid-height)")
    hair_map: StringProperty(name="Hair map", default="@height",
                             description="Where the second painting goes on the hair: a float attribute of the "
                                         "curves (per curve, or per point read at each root; 0: the first painting, "
                                         "1: the second) or @height (the roots' height, bottom to top)")
    mode: EnumProperty(name="Mode", items=_MODES, default="velocity")
    strength: EnumProperty(name="Strength", items=_STRENGTHS, default="default")
    frame_start: IntProperty(name="Start", default=1, min=0)
    frame_end: IntProperty(name="End", default=1, min=0)
    cameras: StringProperty(name="Cameras", default="front",
                            description="front, omniview:N (all around) or ring:N[:ELEV]")
    use_scene_camera: BoolProperty(name="Scene camera", default=False,
                                   description="Stylize for the scene camera (keyed per frame when it moves), "
                                               "so the optimiser sees what the render will")
    model: StringProperty(name="Model", subtype="FILE_PATH", default="",
                          description="A feed-forward model (.safetensors from nst3d train): every frame in one "
                                      "pass, from every viewpoint; no painting needed")
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


classes = (Nst3dPreferences, Nst3dSettings)
