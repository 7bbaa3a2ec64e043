#!/usr/bin/python3
"""How close the points of each large planar region stay to a --planes mesh (issue 25 point 2).

    bench/planes_points.py SCAN PLAIN_MESH VOXEL [PLANES_MESH ...]

The planar regions are those the planes stage finds in the plain mesh (no --planes) with its
default options; the large ones cover at least 100 square voxels (twice --plane-min-area). A
region's points are the scan's points whose closest face of that labelled mesh lies in the
region, that lie within half a voxel (--plane-distance) of its plane (its inliers) and within
half a voxel of the plain mesh (the points the plain mesh represents: all of them lie within
half a voxel of it, and the question is whether they still do of the planar mesh). For every
PLANES_MESH it prints the faces, the share of those points within 0.25 / 0.5 voxel of it (all
together, and in the worst region) and the farthest point. python/tests/test_planes.py uses
the same functions on the room scan. Needs the vdbrecon module on PYTHONPATH.
"""
import sys

import numpy as np
import vdbrecon


def region_points(points, plain, voxel):
    """(points, region of each, number of regions) of the large planar regions of `plain`."""
    regions = vdbrecon.planar_regions(plain, voxel)
    _, face = vdbrecon.mesh_distances(regions.mesh, points)
    label = np.asarray(regions.mesh.regions)[face]
    large = np.array([p.area >= 100.0 * voxel**2 for p in regions.planes] + [False])
    normal = np.array([p.normal for p in regions.planes] + [(0.0, 0.0, 1.0)])
    offset = np.array([p.offset for p in regions.planes] + [0.0])
    inlier = np.abs(np.einsum("ij,ij->i", points, normal[label]) - offset[label]) <= 0.5 * voxel
    represented = vdbrecon.mesh_distances(plain, points)[0] <= 0.5 * voxel
    keep = large[label] & inlier & represented
    return points[keep], label[keep], len(regions.planes)


def coverage(mesh, points, label, count, voxel):
    """(share within 0.25 voxel, share within 0.5 voxel, the worst region's share within 0.5
    voxel, the farthest point in voxels) of the region points against `mesh`."""
    d, _ = vdbrecon.mesh_distances(mesh, points)
    within = d <= 0.5 * voxel
    sizes = np.bincount(label, minlength=count)
    per = np.bincount(label, within, minlength=count)[sizes > 0] / sizes[sizes > 0]
    return np.mean(d <= 0.25 * voxel), np.mean(within), per.min(), d.max() / voxel


def main():
    scan, plain_path, voxel = sys.argv[1], sys.argv[2], float(sys.argv[3])
    points = np.asarray(vdbrecon.read_points(scan).cloud.positions, np.float32)
    plain = vdbrecon.read_mesh(plain_path)
    ours, label, count = region_points(points, plain, voxel)
    print(f"{len(points)} points; {len(np.unique(label))} of the {count} planar regions are "
          f"large, with {len(ours)} points (inliers of their planes within 0.5 voxel of the "
          f"plain mesh)")
    print("| mesh | faces | region points within 0.25 / 0.5 voxel | worst region within 0.5 voxel "
          "| farthest, voxels |")
    print("|---|---|---|---|---|")
    for path in [plain_path] + sys.argv[4:]:
        mesh = vdbrecon.read_mesh(path)
        near, within, worst, far = coverage(mesh, ours, label, count, voxel)
        print(f"| {path.split('/')[-1]} | {len(mesh.faces)} | {near:.4f} / {within:.4f} "
              f"| {worst:.4f} | {far:.2f} |")


if __name__ == "__main__":
    main()
