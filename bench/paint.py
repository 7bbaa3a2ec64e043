#!/usr/bin/python3
"""Colour error of a fused mesh against the pattern bench/fusion_scene painted on the scene:
paint.py MESH.ply REF.ply -> the mean and 99th-percentile |colour - pattern| (0..1, mean of the
three channels) over the mesh's vertices. The pattern, period s = REF's diagonal / 6:
(0.5 + 0.4 sin(x/s), 0.5 + 0.4 cos(y/s), 0.5 + 0.4 sin(z/s + 1))."""
import sys

import numpy as np
import open3d as o3d


def main():
    mesh = o3d.io.read_triangle_mesh(sys.argv[1])
    ref = o3d.io.read_triangle_mesh(sys.argv[2])
    lo, hi = np.asarray(ref.vertices).min(0), np.asarray(ref.vertices).max(0)
    s = np.linalg.norm(hi - lo) / 6.0
    v = np.asarray(mesh.vertices)
    if not mesh.has_vertex_colors() or len(v) == 0:
        print("no colours")
        return
    want = np.stack([0.5 + 0.4 * np.sin(v[:, 0] / s), 0.5 + 0.4 * np.cos(v[:, 1] / s),
                     0.5 + 0.4 * np.sin(v[:, 2] / s + 1.0)], 1)
    e = np.abs(np.asarray(mesh.vertex_colors) - want).mean(1)
    print(f"{e.mean():.4f} / {np.percentile(e, 99):.4f}")


if __name__ == "__main__":
    main()
