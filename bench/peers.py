#!/usr/bin/python3
"""Open3D peers for bench/compare.sh: screened Poisson and ball pivoting.

    peers.py poisson INPUT OUTPUT.ply --depth 10 [--trim 0.01]
    peers.py bpa INPUT OUTPUT.ply [--radii 3,6]

Poisson (Kazhdan and Hoppe 2013, Open3D's `create_from_point_cloud_poisson`, scale 1.1, no
linear fit) is followed by the density trim of Open3D's own tutorial: vertices whose density
(the octree depth of the samples that support them) lies below the `--trim` quantile are
removed, which cuts the balloon that Poisson closes over unsampled regions. Ball pivoting
(Bernardini et al. 1999) rolls balls of radii `--radii` x the mean nearest-neighbour spacing
of the input (the usual recipe: 3x and 6x).

Normals are estimated only when the input has none (k = 10, oriented by Open3D's consistent
tangent plane propagation). Prints one JSON line on stdout: points, normals estimated or not,
seconds per step and the mesh size. Runs under Debian's /usr/bin/python3 (python3-open3d).
"""
import argparse
import json
import sys
import time

import numpy as np
import open3d as o3d


def read_cloud(path, info):
    t = time.perf_counter()
    pcd = o3d.io.read_point_cloud(path)
    info["points"] = len(pcd.points)
    if info["points"] == 0:
        sys.exit(f"peers.py: no points in '{path}'")
    info["normals_estimated"] = not pcd.has_normals()
    if info["normals_estimated"]:
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
        pcd.orient_normals_consistent_tangent_plane(10)
    info["read_s"] = round(time.perf_counter() - t, 3)
    return pcd


def poisson(pcd, args, info):
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=args.depth, scale=1.1, linear_fit=False, n_threads=args.threads)
    density = np.asarray(density)
    cut = np.quantile(density, args.trim)
    mesh.remove_vertices_by_mask(density < cut)
    info.update(depth=args.depth, trim_quantile=args.trim, threads=args.threads)
    return mesh


def ball_pivoting(pcd, args, info):
    spacing = float(np.mean(np.asarray(pcd.compute_nearest_neighbor_distance())))
    radii = [spacing * float(f) for f in args.radii.split(",")]
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector(radii))
    info.update(mean_spacing=spacing, radii=radii)
    return mesh


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("method", choices=["poisson", "bpa"])
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--depth", type=int, default=10, help="Poisson octree depth")
    p.add_argument("--trim", type=float, default=0.01, help="density quantile removed")
    p.add_argument("--radii", default="3,6", help="ball radii, x mean NN spacing")
    p.add_argument("--threads", type=int, default=-1,
                   help="Poisson threads; -1: Open3D's choice (every core)")
    args = p.parse_args()

    info = {"method": args.method}
    pcd = read_cloud(args.input, info)
    t = time.perf_counter()
    mesh = (poisson if args.method == "poisson" else ball_pivoting)(pcd, args, info)
    info["reconstruct_s"] = round(time.perf_counter() - t, 3)
    mesh.remove_unreferenced_vertices()
    info["faces"] = len(mesh.triangles)
    if info["faces"] == 0:
        sys.exit(f"peers.py: {args.method} produced no faces")
    if not o3d.io.write_triangle_mesh(args.output, mesh, write_ascii=False,
                                      write_vertex_normals=False, write_vertex_colors=False):
        sys.exit(f"peers.py: could not write '{args.output}'")
    print(json.dumps(info))


if __name__ == "__main__":
    main()
