"""nst3d for Blender: stylize a smoke domain's OpenVDB cache, or a hair
Curves object, with a painting, from the Physics / Object properties.

One package, two ways in:

- **Blender 4.2 and later**: an extension (``blender_manifest.toml``), its
  zip built by ``tools/build_blender_extension.sh`` with the nst3d wheel
  inside; Blender installs the wheel with it.
- **Blender 3.4 to 4.1**: a legacy add-on (``bl_info`` below); the nst3d
  package must be importable by Blender's Python (its wheel installed into
  it, or its folder set in the add-on's preferences).

What it does:

- **Stylize smoke** (Physics tab of a Fluid domain with an OpenVDB cache):
  the cache's ``fluid_data_####.vdb`` frames are stylized into a new cache
  folder (every other grid kept) and loaded as a Volume object beside the
  domain, at the domain's place; optionally for the scene camera, or in
  one pass by a feed-forward model from ``nst3d train``.
- **Stylize hair** (Object tab of a hair Curves object, or of a mesh with a
  hair particle system): the strands are stylized and written back, with
  the surface mesh (if any) as the collision head. With **Colour** on a
  Curves object the strands' colour is stylized too, written as an
  ``nst3d_color`` point attribute read by a material the object gets.

In the UI the job runs in a background thread with a progress bar in the
panel; **Esc** cancels it and leaves the scene as it was. Without a window
(``blender -b``, tests, farm scripts) it runs in place.

Modules, one job each: ``props`` (settings, preferences), ``operators``
(what each run reads, computes and commits), ``jobs`` (running, progress,
cancelling), ``panels`` (UI), ``volume_io`` and ``hair_io`` (Blender data
in and out).
"""

import bpy
from bpy.props import PointerProperty

from . import operators, panels, props

bl_info = {
    "name": "nst3d: stylize smoke and hair with a painting",
    "author": "nst3d",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Physics (smoke domain), Properties > Object (hair curves)",
    "description": "Neural style transfer for smoke volumes and hair grooms (nst3d)",
    "category": "Physics",
}

_classes = props.classes + operators.classes + panels.classes


def register():
    for c in _classes:
        bpy.utils.register_class(c)
    bpy.types.Object.nst3d = PointerProperty(type=props.Nst3dSettings)


def unregister():
    del bpy.types.Object.nst3d
    for c in reversed(_classes):
        bpy.utils.unregister_class(c)
