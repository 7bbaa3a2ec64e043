#!/usr/bin/python3
"""Point sets for the benchmarks (bench/compare.sh, bench/scaling.sh).

    synth.py subsample INPUT OUTPUT.ply FRACTION [--seed S]
    synth.py scans MESH OUTPUT.ply --points N [--views V] [--noise M] [--seed S]

`subsample` keeps a random FRACTION of the points (without replacement, seeded), with their
normals. `scans` simulates V range scans of a triangle mesh: each view is a pinhole camera on a
Fibonacci sphere at 2x the mesh's bounding radius, looking at its centre, casting a square grid
of rays (Open3D's Embree ray casting); a hit keeps the face normal turned towards the camera,
gets Gaussian range noise of M world units along the ray and the view's registration error (a
translation of M/2), and hits at grazing angles (|cos| < 0.15) are dropped, as a triangulation
scanner drops them. The grid is sized so the views give at least N hits; N of them are kept.
Both write binary little-endian PLY with float x y z nx ny nz, and are deterministic for a seed.
"""
import argparse
import sys

import numpy as np
import open3d as o3d


def write_ply(path, points, normals, comments):
    """Binary little-endian PLY, float32 x y z nx ny nz."""
    data = np.empty((len(points), 6), dtype="<f4")
    data[:, :3] = points
    data[:, 3:] = normals
    header = ["ply", "format binary_little_endian 1.0"]
    header += ["comment " + c for c in comments]
    header += ["element vertex %d" % len(points)]
    header += ["property float " + p for p in ("x", "y", "z", "nx", "ny", "nz")]
    header += ["end_header", ""]
    with open(path, "wb") as f:
        f.write("\n".join(header).encode("ascii"))
        f.write(data.tobytes())


def subsample(args):
    pcd = o3d.io.read_point_cloud(args.input)
    n = len(pcd.points)
    if n == 0 or not pcd.has_normals():
        sys.exit(f"synth.py: '{args.input}' has no points with normals")
    if not 0 < args.fraction <= 1:
        sys.exit("synth.py: FRACTION must be in (0, 1]")
    keep = np.sort(np.random.default_rng(args.seed).choice(n, int(round(n * args.fraction)),
                                                           replace=False))
    write_ply(args.output, np.asarray(pcd.points)[keep], np.asarray(pcd.normals)[keep],
              ["subsample of %s: %d of %d points (fraction %g, seed %d)" %
               (args.input, len(keep), n, args.fraction, args.seed)])


def fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - y * y)
    t = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(t), y, r * np.sin(t)], axis=1)


def sample_mesh(verts, faces, count, rng):
    """`count` points uniform by area, with their faces' unit normals."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    ok = area > 0
    a, b, c, cross, area = a[ok], b[ok], c[ok], cross[ok], area[ok]
    f = rng.choice(len(area), count, p=area / area.sum())
    s, t = np.sqrt(rng.random(count))[:, None], rng.random(count)[:, None]
    pts = (1 - s) * a[f] + s * (1 - t) * b[f] + s * t * c[f]
    return pts, cross[f] / area[f, None]


def range_image(pts, nrm, view, pitch):
    """One orthographic scan along -view: per pixel of `pitch` world units, the sample nearest
    to the camera (a z-buffer over dense samples); grazing hits (|cos| < 0.15) are dropped.
    Returns the indices of the samples seen."""
    up = np.array([0.0, 1.0, 0.0]) if abs(view[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(up, view)
    u /= np.linalg.norm(u)
    v = np.cross(view, u)
    ij = np.floor(np.stack([pts @ u, pts @ v], axis=1) / pitch).astype(np.int64)
    ij -= ij.min(axis=0)
    pixel = ij[:, 0] * (ij[:, 1].max() + 1) + ij[:, 1]
    order = np.argsort(-(pts @ view), kind="stable")  # nearest to the camera first
    _, first = np.unique(pixel[order], return_index=True)
    seen = order[first]
    return seen[np.abs(nrm[seen] @ view) >= 0.15]


def scans(args):
    mesh = o3d.io.read_triangle_mesh(args.mesh)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.triangles)
    if len(faces) == 0:
        sys.exit(f"synth.py: no triangles in '{args.mesh}'")
    rng = np.random.default_rng(args.seed)
    # Dense samples: about 10 per pixel of the final scans where a view sees the surface
    # head-on (a view sees about 40 % of the area).
    pts, nrm = sample_mesh(verts, faces, max(25 * args.points // args.views, 200000), rng)
    views = fibonacci_sphere(args.views)
    area = np.linalg.norm(np.cross(verts[faces[:, 1]] - verts[faces[:, 0]],
                                   verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1).sum() / 2
    pitch = np.sqrt(0.3 * area * args.views / args.points)  # a first guess; hits ~ 1 / pitch^2
    for _ in range(4):
        seen = [range_image(pts, nrm, w, pitch) for w in views]
        hits = sum(len(i) for i in seen)
        if hits >= args.points:
            break
        pitch *= np.sqrt(hits / (1.05 * args.points))
    out_p, out_n = [], []
    for w, i in zip(views, seen):
        out_p.append(pts[i] + rng.normal(0.0, args.noise, len(i))[:, None] * w +
                     rng.normal(0.0, args.noise / 2, 3))
        out_n.append(nrm[i] * np.sign(nrm[i] @ w)[:, None])  # face the camera
    out_p, out_n = np.concatenate(out_p), np.concatenate(out_n)
    if len(out_p) < args.points:
        sys.exit(f"synth.py: only {len(out_p)} hits for {args.points} points")
    keep = np.sort(rng.choice(len(out_p), args.points, replace=False))
    write_ply(args.output, out_p[keep], out_n[keep],
              ["%d orthographic virtual scans of %s, pixel %.3g, range noise %g, seed %d" %
               (args.views, args.mesh, pitch, args.noise, args.seed)])


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("subsample")
    s.add_argument("input")
    s.add_argument("output")
    s.add_argument("fraction", type=float)
    s.add_argument("--seed", type=int, default=1)
    v = sub.add_parser("scans")
    v.add_argument("mesh")
    v.add_argument("output")
    v.add_argument("--points", type=int, required=True)
    v.add_argument("--views", type=int, default=48)
    v.add_argument("--noise", type=float, default=1e-4, help="range noise sigma, world units")
    v.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    (subsample if args.command == "subsample" else scans)(args)


if __name__ == "__main__":
    main()
