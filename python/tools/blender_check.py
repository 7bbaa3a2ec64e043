"""Runs inside Blender (3.4, headless): loads a vdbrecon .vdb, renders its `density` grid with
Cycles to a PNG, and meshes its `sdf` grid with a VOLUME_TO_MESH modifier. Prints one JSON line
(prefixed "BLENDER_CHECK ") with the grids Blender saw and the modifier mesh's statistics.

    blender -b --factory-startup --python blender_check.py -- VOLUME.vdb OUT.png [SAMPLES [PERCENT]]

SAMPLES: Cycles samples per pixel (32); PERCENT: resolution percentage of 480 x 360 (100).
"""
import json
import sys
import time

import os
import bpy
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blender_common import add_camera, render_cycles  # noqa: E402

argv = sys.argv[sys.argv.index("--") + 1:]
vdb_path, png_path = argv[0], argv[1]
samples = int(argv[2]) if len(argv) > 2 else 32
percent = int(argv[3]) if len(argv) > 3 else 100

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene

bpy.ops.object.volume_import(filepath=vdb_path)
vol = bpy.context.active_object
vol.data.grids.load()
grids = [{"name": g.name, "data_type": g.data_type, "channels": g.channels}
         for g in vol.data.grids]

# The sdf grid as a mesh (what Blender's own OpenVDB volumeToMesh makes of it).
mesh_obj = bpy.data.objects.new("sdf_mesh", bpy.data.meshes.new("sdf_mesh"))
scene.collection.objects.link(mesh_obj)
mod = mesh_obj.modifiers.new("sdf", "VOLUME_TO_MESH")
mod.object = vol
mod.grid_name = "sdf"
mod.threshold = 0.0  # the zero crossing (the default is 0.1)
mod.resolution_mode = "GRID"
mod.adaptivity = 0.0
depsgraph = bpy.context.evaluated_depsgraph_get()
evaluated = mesh_obj.evaluated_get(depsgraph)
me = evaluated.to_mesh()
co = [v.co.copy() for v in me.vertices]
mesh_stats = {
    "vertices": len(me.vertices),
    "polygons": len(me.polygons),
    "triangles": sum(len(p.vertices) - 2 for p in me.polygons),
    "bbox_min": [min(c[i] for c in co) for i in range(3)] if co else None,
    "bbox_max": [max(c[i] for c in co) for i in range(3)] if co else None,
}
evaluated.to_mesh_clear()
mesh_obj.hide_render = True  # the picture shows the density grid only

# Render the density grid: Cycles' volume shader reads the grid named "density".
mat = bpy.data.materials.new("density")
mat.use_nodes = True
nodes = mat.node_tree.nodes
nodes.clear()
pv = nodes.new("ShaderNodeVolumePrincipled")
pv.inputs["Color"].default_value = (0.9, 0.55, 0.25, 1.0)
# Optical depth ~2 per voxel: the density shell (3 voxels thick) reads as a surface at any scale.
voxel = vol.data.grids["density"].matrix_object[0][0]
pv.inputs["Density"].default_value = 2.0 / voxel
pv.inputs["Density Attribute"].default_value = "density"
out = nodes.new("ShaderNodeOutputMaterial")
mat.node_tree.links.new(pv.outputs["Volume"], out.inputs["Volume"])
vol.data.materials.append(mat)

corners = [vol.matrix_world @ Vector(c) for c in vol.bound_box]
lo = Vector([min(c[i] for c in corners) for i in range(3)])
hi = Vector([max(c[i] for c in corners) for i in range(3)])
centre, size = (lo + hi) / 2, (hi - lo).length

# Scans (the Stanford bunny) are y-up: look from +z, slightly from the right and above.
cam = add_camera(scene, centre + Vector((0.55, 0.45, 1.5)) * size * 0.95, centre,
                 Vector((0.0, 1.0, 0.0)))
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.data.energy = 4.0
sun.matrix_world = cam.matrix_world.to_3x3().to_4x4() @ Matrix.Rotation(0.6, 4, "X") @ \
    Matrix.Rotation(-0.5, 4, "Y")  # roughly from behind the camera, upper right
scene.collection.objects.link(sun)
world = bpy.data.worlds.new("world")
world.color = (0.05, 0.05, 0.06)
scene.world = world

start = time.time()
render_cycles(scene, png_path, samples, 480, 360, percent)

print("BLENDER_CHECK " + json.dumps({
    "grids": grids,
    "matrix": [list(r) for r in vol.data.grids[0].matrix_object] if len(vol.data.grids) else None,
    "mesh": mesh_stats,
    "render_seconds": round(time.time() - start, 2),
    "png": png_path,
}))
