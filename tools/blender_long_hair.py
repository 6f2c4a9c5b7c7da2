# Grows a long-hair groom in Blender: guide hairs on the upper half of a head
# stand-in (a sphere of radius 1, z up), twice its radius long, then lets them
# fall under gravity with Blender's hair dynamics, colliding with the head, so
# they drape over it and hang as long hair does. Writes the strands as a
# binary strand PLY (the layout of the shared monkey_curly groom) and the head
# as OBJ. Headless, in Debian's Blender:
#
#   blender -b --factory-startup --python tools/blender_long_hair.py -- OUTDIR NAME GUIDES CHILDREN SEED
#   e.g. blender -b --factory-startup --python tools/blender_long_hair.py -- out long_hair 600 6 3
import bpy, sys, os, struct

argv = sys.argv[sys.argv.index("--") + 1:]
out, name, guides, children, seed = argv[0], argv[1], int(argv[2]), int(argv[3]), int(argv[4])
FRAMES = 80  # enough for the strands to settle under gravity
os.makedirs(out, exist_ok=True)
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, segments=48, ring_count=24)
head = bpy.context.active_object
# The scalp: the cap above the equator, tilted back as a hairline is.
scalp = head.vertex_groups.new(name="scalp")
scalp.add([v.index for v in head.data.vertices if v.co.z - 0.35 * v.co.y > 0.05], 1.0, "REPLACE")
head.modifiers.new("collision", "COLLISION")
head.collision.thickness_outer = 0.02
psm = head.modifiers.new("hair", "PARTICLE_SYSTEM")
ps = head.particle_systems[0]
s = ps.settings
s.type = "HAIR"
s.count = guides
s.hair_length = 2.0
s.hair_step = 16
s.emit_from = "FACE"
s.use_emit_random = True
ps.vertex_group_density = "scalp"
ps.seed = seed
if children:
    s.child_type = "INTERPOLATED"
    s.child_nbr = children
    s.rendered_child_count = children
    s.clump_factor = 0.2
    s.roughness_1 = 0.01
    s.display_step = 4
    s.render_step = 4
ps.use_hair_dynamics = True
cs = ps.cloth.settings
cs.quality = 8
cs.mass = 1.0
cs.bending_stiffness = 0.02
cs.pin_stiffness = 1.0
ps.cloth.collision_settings.use_collision = True
scene = bpy.context.scene
scene.frame_start, scene.frame_end = 1, FRAMES
ps.point_cache.frame_end = FRAMES
for f in range(1, FRAMES + 1):
    scene.frame_set(f)
dg = bpy.context.evaluated_depsgraph_get()
eo = head.evaluated_get(dg)
eps = eo.particle_systems[0]
nkeys = 2 ** s.display_step + 1 if children else s.hair_step + 1
total = len(eps.particles) + len(eps.child_particles)
strands = []
for i in range(total):
    pts = [tuple(eps.co_hair(eo, particle_no=i, step=k)) for k in range(nkeys)]
    if any(p != (0.0, 0.0, 0.0) for p in pts):
        strands.append(pts)
tmp = os.path.join(out, name + ".ply.tmp")
with open(tmp, "wb") as f:
    nv = sum(len(p) for p in strands)
    f.write(("ply\nformat binary_little_endian 1.0\ncomment grown by Blender particle hair, draped by hair dynamics\n"
             f"element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
             "property uchar red\nproperty uchar green\nproperty uchar blue\n"
             f"element strand {len(strands)}\nproperty ushort nsegs\nend_header\n").encode())
    for p in strands:
        for q in p:
            f.write(struct.pack("<fffBBB", q[0], q[1], q[2], 90, 60, 40))
    for p in strands:
        f.write(struct.pack("<H", len(p) - 1))
os.replace(tmp, os.path.join(out, name + ".ply"))
print("strands", len(strands), "points", nv)
head.modifiers.remove(psm)
head.modifiers.remove(head.modifiers["collision"])
bpy.ops.wm.obj_export(filepath=os.path.join(out, name + "_mesh.obj"), export_selected_objects=False,
                      export_uv=False, export_materials=False, forward_axis="Y", up_axis="Z")
print("groom written", out, name)
