#!/usr/bin/python3
"""Open3D's ScalableTSDFVolume on a transforms.json scene of 16-bit PNG depth and 8-bit colour
(file_path; RGB8 colour when every frame has it) (the peer run of bench/fusion.sh):
fusion_open3d.py SCENE_JSON OUT_MESH VOXEL [SDF_TRUNC_VOXELS=4]
Prints the integrate and extract times (seconds) as one JSON line."""
import json
import os
import sys
import time

import numpy as np
import open3d as o3d


def main():
    scene, out, voxel = sys.argv[1], sys.argv[2], float(sys.argv[3])
    trunc = float(sys.argv[4]) if len(sys.argv) > 4 else 4.0
    with open(scene) as f:
        s = json.load(f)
    units = 1.0 / s.get("depth_scale", 0.001)
    base = os.path.dirname(scene)
    colored = all(os.path.isfile(os.path.join(base, fr.get("file_path", ""))) for fr in s["frames"])
    t0 = time.perf_counter()
    kind = o3d.pipelines.integration.TSDFVolumeColorType
    vol = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=voxel, sdf_trunc=trunc * voxel,
        color_type=kind.RGB8 if colored else kind.NoColor)
    # NeRF's principal point counts from the image corner; Open3D's from the first pixel centre.
    intr = o3d.camera.PinholeCameraIntrinsic(int(s["w"]), int(s["h"]), s["fl_x"], s["fl_y"],
                                             s["cx"] - 0.5, s["cy"] - 0.5)
    for fr in s["frames"]:
        depth = o3d.io.read_image(os.path.join(base, fr["depth_file_path"]))
        color = (o3d.io.read_image(os.path.join(base, fr["file_path"])) if colored
                 else o3d.geometry.Image(np.zeros((s["h"], s["w"], 3), np.uint8)))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, depth, depth_scale=units, depth_trunc=1e6, convert_rgb_to_intensity=False)
        m = np.array(fr["transform_matrix"], dtype=np.float64)
        m[:3, 1:3] *= -1.0  # OpenGL to OpenCV camera axes
        vol.integrate(rgbd, intr, np.linalg.inv(m))  # Open3D takes world-to-camera
    t1 = time.perf_counter()
    mesh = vol.extract_triangle_mesh()
    t2 = time.perf_counter()
    o3d.io.write_triangle_mesh(out, mesh)
    print(json.dumps({"integrate_s": t1 - t0, "extract_s": t2 - t1,
                      "total_s": time.perf_counter() - t0}))


if __name__ == "__main__":
    main()
