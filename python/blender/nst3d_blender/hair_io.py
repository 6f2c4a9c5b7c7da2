"""Hair in and out of Blender: the strands of a hair Curves object (or of a
mesh's hair particle system, through Blender's own conversions), their
surface mesh as the collision head, and the stylized colour as a point
attribute with a material that reads it."""

import bpy
import numpy as np

# Not "color": Blender 3.4's Cycles reads a Curves point attribute of that
# name as black through an Attribute node (measured); any other name works.
HAIR_COLOR = "nst3d_color"


def hair_curves(obj):
    return obj is not None and obj.type == "CURVES"


def hair_particles(obj):
    """The active hair particle system of a mesh, else None."""
    if obj is None or obj.type != "MESH":
        return None
    ps = obj.particle_systems.active
    return ps if ps is not None and ps.settings.type == "HAIR" else None


def curves_from_particles(context, mesh_obj):
    """A temporary hair Curves object holding the mesh's particle hair
    (Blender's own conversion), with the mesh as its surface. The active
    object and the selection are left as they were."""
    before = set(bpy.data.objects)
    view_layer = context.view_layer
    active = view_layer.objects.active
    selected = [o for o in view_layer.objects if o.select_get()]
    with context.temp_override(object=mesh_obj, active_object=mesh_obj, selected_objects=[mesh_obj]):
        bpy.ops.curves.convert_from_particle_system()
    new = [o for o in bpy.data.objects if o not in before and o.type == "CURVES"]
    for o in view_layer.objects:
        o.select_set(o in selected)
    view_layer.objects.active = active
    if not new:
        raise RuntimeError(f"Blender could not convert the hair of {mesh_obj.name} to curves")
    curves = new[0]
    curves.data.surface = mesh_obj
    return curves


def remove_curves(curves_obj):
    """Removes a Curves object and its data."""
    data = curves_obj.data
    bpy.data.objects.remove(curves_obj)
    if data.users == 0:
        bpy.data.hair_curves.remove(data)


def particles_from_curves(context, curves_obj):
    """Writes a Curves object back into its surface's hair particle system
    (Blender's own conversion) and removes the Curves object."""
    with context.temp_override(object=curves_obj, active_object=curves_obj, selected_objects=[curves_obj]):
        r = bpy.ops.curves.convert_to_particle_system()
    if r != {"FINISHED"}:
        raise RuntimeError(f"Blender could not write the strands back into the particle system ({r})")
    remove_curves(curves_obj)


def read_strands(curves):
    """(points (n, 3) float32, per-strand point counts) of Curves data."""
    n = len(curves.points)
    points = np.empty(n * 3, dtype=np.float32)
    curves.attributes["position"].data.foreach_get("vector", points)
    counts = np.array([c.points_length for c in curves.curves], dtype=np.int64)
    return points.reshape(-1, 3), counts


def read_surface(obj):
    """The Curves object's surface mesh as (vertices, triangles) in the
    curves' own space, or None."""
    surface = obj.data.surface
    if surface is None or surface.type != "MESH":
        return None
    m = surface.data
    verts = np.empty(len(m.vertices) * 3, dtype=np.float32)
    m.vertices.foreach_get("co", verts)
    m.calc_loop_triangles()
    tris = np.empty(len(m.loop_triangles) * 3, dtype=np.int64)
    m.loop_triangles.foreach_get("vertices", tris)
    # The curves live in the object's space, the surface in its own.
    to_curves = obj.matrix_world.inverted() @ surface.matrix_world
    rot = np.array(to_curves.to_3x3(), dtype=np.float32)
    v = verts.reshape(-1, 3) @ rot.T + np.array(to_curves.translation, dtype=np.float32)
    return v.astype(np.float32), tris.reshape(-1, 3)


def read_map(curves, name):
    """One value per strand from the float attribute `name` of Curves data:
    a curve attribute's own, a point attribute's at each strand's root."""
    attr = curves.attributes.get(name)
    if attr is None or attr.data_type != "FLOAT" or attr.domain not in ("CURVE", "POINT"):
        raise RuntimeError(f"the hair has no float curve or point attribute '{name}' for Hair map")
    values = np.empty(len(attr.data), dtype=np.float32)
    attr.data.foreach_get("value", values)
    if attr.domain == "CURVE":
        return values
    counts = np.array([c.points_length for c in curves.curves], dtype=np.int64)
    return values[np.concatenate([[0], np.cumsum(counts)[:-1]])]


def read_colors(curves):
    """The strands' colours (n, 3) from the `HAIR_COLOR` attribute, or None."""
    attr = curves.attributes.get(HAIR_COLOR)
    if attr is None or attr.domain != "POINT" or attr.data_type not in ("FLOAT_COLOR", "BYTE_COLOR"):
        return None
    rgba = np.empty(len(curves.points) * 4, dtype=np.float32)
    attr.data.foreach_get("color", rgba)
    return rgba.reshape(-1, 4)[:, :3]


def write_strands(obj, points, colors=None):
    """Writes stylized points (and colours, with a material reading them)
    into a Curves object."""
    data = obj.data
    data.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(points, np.float32).ravel())
    if colors is not None:
        attr = data.attributes.get(HAIR_COLOR)
        if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_COLOR":
            if attr is not None:
                data.attributes.remove(attr)
            attr = data.attributes.new(HAIR_COLOR, "FLOAT_COLOR", "POINT")
        rgba = np.concatenate([colors, np.ones((len(colors), 1), np.float32)], axis=1)
        attr.data.foreach_set("color", rgba.astype(np.float32).ravel())
        data.materials.clear()
        data.materials.append(hair_color_material(obj.name + "_nst3d"))
    data.update_tag()


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
