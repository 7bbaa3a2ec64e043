"""Runs inside Blender (3.4, headless): imports a textured vdbrecon OBJ (`--texture`) with
Blender's own OBJ importer, and reports what Blender made of it: objects, polygons, the UV
layer, the materials and the image each one's Principled BSDF reads, and SAMPLES points spread
over the textured triangles by area, each in the file's coordinates with the colour of the
image texel under its texture coordinates (read through Blender's image, origin bottom-left).
With OUT.png, Cycles renders the mesh with its materials (the plain one showing the vertex
colours) from the side of the origin (a camera-frame scan's sensor). Prints one JSON
line prefixed "BLENDER_TEXTURE ".

    blender -b --factory-startup --python blender_texture_check.py -- MESH.obj [OUT.png [SAMPLES [CYCLES_SAMPLES [PERCENT]]]]
"""
import json
import sys

import os
import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blender_common import add_camera, render_cycles  # noqa: E402

argv = sys.argv[sys.argv.index("--") + 1:]
obj_path = argv[0]
png_path = argv[1] if len(argv) > 1 and argv[1] != "-" else None
samples = int(argv[2]) if len(argv) > 2 else 200
cycles_samples = int(argv[3]) if len(argv) > 3 else 16
percent = int(argv[4]) if len(argv) > 4 else 100

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
# The file's axes as Blender's (no y-up conversion), so positions compare with the file's.
bpy.ops.wm.obj_import(filepath=obj_path, forward_axis="Y", up_axis="Z")
objects = [o for o in scene.objects if o.type == "MESH"]
obj = objects[0]
me = obj.data


def material_info(mat):
    image = None
    if mat.use_nodes:
        for node in mat.node_tree.nodes:
            if node.type == "TEX_IMAGE" and node.image is not None:
                img = node.image
                image = {"name": img.name, "filepath": bpy.path.abspath(img.filepath),
                         "size": list(img.size), "has_data": bool(img.has_data),
                         "linked": any(l.to_node.type == "BSDF_PRINCIPLED"
                                       for l in node.outputs["Color"].links)}
    return {"name": mat.name, "image": image}


materials = [material_info(m) for m in me.materials]
uv = me.uv_layers.active
result = {
    "objects": len(objects),
    "vertices": len(me.vertices),
    "polygons": len(me.polygons),
    "uv_layers": len(me.uv_layers),
    "color_attributes": len(me.color_attributes),
    "materials": materials,
    "samples": [],
}

# Texel colours under the textured polygons' centres.
textured = [i for i, m in enumerate(me.materials) if material_info(m)["image"]]
if textured and uv is not None:
    img = next(n.image for n in me.materials[textured[0]].node_tree.nodes
               if n.type == "TEX_IMAGE" and n.image is not None)
    w, h = img.size
    pixels = img.pixels[:]  # RGBA floats, row 0 at the bottom; byte images: value / 255
    polys = [p for p in me.polygons if p.material_index in textured and p.loop_total == 3]
    # SAMPLES points spread over the textured triangles by area (stratified, deterministic),
    # each at quasi-random barycentric coordinates (the R2 sequence).
    cumulative, total = [], 0.0
    for p in polys:
        total += p.area
        cumulative.append(total)
    j = 0
    for i in range(samples if polys else 0):
        target = (i + 0.5) / samples * total
        while j < len(polys) - 1 and cumulative[j] < target:
            j += 1
        p = polys[j]
        r1, r2 = (0.5 + 0.7548776662 * (i + 1)) % 1.0, (0.5 + 0.5698402910 * (i + 1)) % 1.0
        if r1 + r2 > 1.0:
            r1, r2 = 1.0 - r1, 1.0 - r2
        bary = (1.0 - r1 - r2, r1, r2)
        loops = list(p.loop_indices)
        point = sum((me.vertices[me.loops[l].vertex_index].co * b for l, b in zip(loops, bary)),
                    Vector())
        uvp = sum((uv.data[l].uv * b for l, b in zip(loops, bary)), Vector((0.0, 0.0)))
        x = min(w - 1, max(0, int(uvp.x * w)))
        y = min(h - 1, max(0, int(uvp.y * h)))
        k = 4 * (y * w + x)
        result["samples"].append([point.x, point.y, point.z] + list(pixels[k:k + 3]))

if png_path:
    lo = Vector([min(v.co[i] for v in me.vertices) for i in range(3)])
    hi = Vector([max(v.co[i] for v in me.vertices) for i in range(3)])
    centre, size = (lo + hi) / 2, (hi - lo).length
    # Camera-frame scans (x right, y down, z forward): look from the sensor's side (the
    # origin), far enough back for the whole mesh to fit the 50 mm lens's 40 degrees.
    view = (Vector((0.0, 0.0, 0.0)) - centre).normalized()
    add_camera(scene, centre + view * (0.32 * size / 0.36), centre, Vector((0.0, -1.0, 0.0)))
    # The faces without texture show the vertex colours (the OBJ's `v x y z r g b`), which
    # the imported plain material does not read.
    if len(me.color_attributes):
        if not me.materials:  # a plain OBJ: no material at all
            plain = bpy.data.materials.new("vertex_colours")
            plain.use_nodes = True
            me.materials.append(plain)
        for mat in me.materials:
            if mat.use_nodes and not material_info(mat)["image"]:
                bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
                attr = mat.node_tree.nodes.new("ShaderNodeVertexColor")
                attr.layer_name = me.color_attributes[0].name
                mat.node_tree.links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    world = bpy.data.worlds.new("world")
    world.color = (0.9, 0.9, 0.9)  # even light from every side, the texture's own colours
    scene.world = world
    scene.view_settings.view_transform = "Standard"
    render_cycles(scene, png_path, cycles_samples, 640, 480, percent)
    result["render"] = png_path

print("BLENDER_TEXTURE " + json.dumps(result))
