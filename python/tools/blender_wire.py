"""Runs inside Blender (3.4, headless): renders a mesh (PLY) shaded, with its edges drawn over it
(a Wireframe modifier on a copy, dark), to show how many triangles a surface takes -- the
before/after pictures of `--planes` in the README. The camera looks at the mesh's bounding-box
centre from DIRECTION (x,y,z, from the centre towards the camera), with UP upwards.

    blender -b --factory-startup --python blender_wire.py -- MESH.ply OUT.png WIRE DIRECTION UP \
        [WIDTH HEIGHT [CYCLES_SAMPLES [DISTANCE]]]

WIRE is the drawn edges' thickness in the mesh's units; DISTANCE the camera's distance from the
centre in bounding-box radii (2).
"""
import os
import sys

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blender_common import add_camera, render_cycles  # noqa: E402

argv = sys.argv[sys.argv.index("--") + 1:]
mesh_path, png_path, wire = argv[0], argv[1], float(argv[2])
direction = Vector([float(x) for x in argv[3].split(",")]).normalized()
up = Vector([float(x) for x in argv[4].split(",")])
width = int(argv[5]) if len(argv) > 5 else 960
height = int(argv[6]) if len(argv) > 6 else 720
samples = int(argv[7]) if len(argv) > 7 else 16
distance = float(argv[8]) if len(argv) > 8 else 2.0

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
bpy.ops.preferences.addon_enable(module="io_mesh_ply")
bpy.ops.import_mesh.ply(filepath=mesh_path)  # Blender 3.4's importer: the file's own axes
obj = [o for o in scene.objects if o.type == "MESH"][0]


def material(name, colour, emission=False):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    if emission:
        nodes.clear()
        out = nodes.new("ShaderNodeOutputMaterial")
        em = nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = colour
        mat.node_tree.links.new(em.outputs["Emission"], out.inputs["Surface"])
    else:
        nodes["Principled BSDF"].inputs["Base Color"].default_value = colour
    return mat


obj.data.materials.clear()
obj.data.materials.append(material("surface", (0.75, 0.75, 0.75, 1.0)))
edges = obj.copy()
edges.data = obj.data.copy()
scene.collection.objects.link(edges)
edges.data.materials.clear()
edges.data.materials.append(material("edges", (0.02, 0.02, 0.05, 1.0), emission=True))
modifier = edges.modifiers.new("wire", "WIREFRAME")
modifier.thickness = wire
modifier.use_replace = True
modifier.use_even_offset = False  # its offset blows up at the slivers marching cubes makes

corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
centre = sum(corners, Vector()) / 8.0
radius = max((c - centre).length for c in corners)
add_camera(scene, centre + direction * radius * distance, centre, up)
scene.camera.data.lens = 35.0
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.data.energy = 3.0
sun.rotation_euler = direction.to_track_quat("Z", "Y").to_euler()
scene.collection.objects.link(sun)
scene.world = bpy.data.worlds.new("world")
scene.world.color = (0.35, 0.35, 0.38)
render_cycles(scene, png_path, samples, width, height, 100)
