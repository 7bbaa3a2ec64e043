"""What the Blender check scripts share (imported inside Blender 3.4): a camera aimed at a point,
and a Cycles render on the CPU to a PNG."""
import bpy
from mathutils import Matrix


def add_camera(scene, location, target, up):
    """A camera at `location` looking at `target`, `up` (a Vector) upwards in the picture; it
    becomes the scene's camera."""
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    forward = (target - location).normalized()
    right = forward.cross(up).normalized()
    up = right.cross(forward)
    cam.matrix_world = Matrix((
        (right.x, up.x, -forward.x, location.x),
        (right.y, up.y, -forward.y, location.y),
        (right.z, up.z, -forward.z, location.z),
        (0.0, 0.0, 0.0, 1.0)))
    scene.camera = cam
    return cam


def render_cycles(scene, png_path, samples, width, height, percent):
    """Renders the scene with Cycles on the CPU to `png_path`."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False  # Debian's Blender is built without OpenImageDenoise
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = percent
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = png_path
    bpy.ops.render.render(write_still=True)
