# Bakes a Blender Mantaflow smoke plume (headless) to an OpenVDB cache with
# density and velocity, with knobs for making plumes unlike the shared one.
#
#   blender -b --factory-startup --python-exit-code 1 -P tools/blender_bake_plume.py -- \
#       OUTDIR RES FRAMES [--offset X Y] [--radius R] [--vorticity V] \
#       [--velocity VX VY VZ] [--alpha A] [--beta B] [--noise]
#
# With no options it builds the same scene as ../shared/tools/blender_bake_smoke.py
# (domain 2 x 2 x 3 from z = 0, sphere inflow of radius 0.25 at (0, 0, 0.4),
# vorticity 0.1, buoyancy alpha = beta = 1 (Blender's defaults), noise off):
# baked at resolution 48 for 40 frames (with e.g. `--radius 0.25` to force this
# script) its 40 files differ from the shared plume48 only in the 36-byte file
# UUID of the header. Usually called through tools/bake_plume.sh.
#
#   --offset X Y       move the source sideways (domain units; the domain spans -1..1)
#   --radius R         source sphere radius (0.25)
#   --vorticity V      domain vorticity confinement (0.1)
#   --velocity VX VY VZ  initial velocity of the emitted smoke (flow_settings
#                      use_initial_velocity / velocity_coord, domain units per second)
#   --alpha A          buoyancy from density (domain alpha; negative sinks) (1.0)
#   --beta B           buoyancy from heat (domain beta) (1.0)
#   --noise            bake Mantaflow's wavelet noise too (off; cached separately
#                      under OUTDIR/noise, fluid_data_####.vdb stays the base grid)
import argparse
import os
import sys

import bpy

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
ap = argparse.ArgumentParser(prog="blender_bake_plume.py")
ap.add_argument("out")
ap.add_argument("res", type=int)
ap.add_argument("frames", type=int)
ap.add_argument("--offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"))
ap.add_argument("--radius", type=float, default=0.25)
ap.add_argument("--vorticity", type=float, default=0.1)
ap.add_argument("--velocity", type=float, nargs=3, default=None, metavar=("VX", "VY", "VZ"))
ap.add_argument("--alpha", type=float, default=None)
ap.add_argument("--beta", type=float, default=None)
ap.add_argument("--noise", action="store_true")
a = ap.parse_args(argv)
if a.res < 8 or a.frames < 1 or a.radius <= 0:
    ap.error("need RES >= 8, FRAMES >= 1, --radius > 0")

bpy.ops.wm.read_factory_settings(use_empty=True)
scn = bpy.context.scene
scn.frame_start, scn.frame_end = 1, a.frames

bpy.ops.mesh.primitive_cube_add(size=2, location=(0, 0, 1.5))
dom = bpy.context.object
dom.scale = (1.0, 1.0, 1.5)
bpy.ops.object.transform_apply(scale=True)

bpy.ops.mesh.primitive_uv_sphere_add(radius=a.radius, location=(a.offset[0], a.offset[1], 0.4))
src = bpy.context.object
m = src.modifiers.new("Fluid", "FLUID")
m.fluid_type = "FLOW"
fs = m.flow_settings
fs.flow_type = "SMOKE"
fs.flow_behavior = "INFLOW"
fs.flow_source = "MESH"
fs.surface_distance = 0.5
if a.velocity is not None:
    fs.use_initial_velocity = True
    fs.velocity_coord = a.velocity

d = dom.modifiers.new("Fluid", "FLUID")
d.fluid_type = "DOMAIN"
ds = d.domain_settings
ds.domain_type = "GAS"
ds.resolution_max = a.res
ds.cache_directory = a.out
ds.cache_type = "ALL"
ds.cache_data_format = "OPENVDB"
ds.cache_frame_start, ds.cache_frame_end = 1, a.frames
ds.use_noise = a.noise
ds.vorticity = a.vorticity
if a.alpha is not None:
    ds.alpha = a.alpha
if a.beta is not None:
    ds.beta = a.beta

print("PLUME", vars(a), "alpha", ds.alpha, "beta", ds.beta, flush=True)
with bpy.context.temp_override(object=dom, active_object=dom, selected_objects=[dom]):
    r = bpy.ops.fluid.bake_all()
print("BAKE", r, sorted(os.listdir(a.out)))
if "FINISHED" not in r:
    sys.exit(1)
