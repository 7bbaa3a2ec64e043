#!/usr/bin/python3
"""A synthetic terrain as a binary PLY with exact normals: N million points drawn uniformly at
random over a square of `size` metres, z = rolling hills (a sum of waves) plus Gaussian noise,
normals from the surface's analytic gradient. For the tiled benchmark (bench/tiles.sh).
With --las, the same points (the same seed draws the same ones) as airborne LiDAR has them: a
LAS 1.2 file of point format 0, millimetre coordinates, no normals (class 2, ground).

    bench/terrain.py OUT.ply MILLIONS [--size 2000] [--noise 0.02] [--seed 1]
    bench/terrain.py OUT.las MILLIONS --las [--size 2000] ...
"""
import argparse
import struct

import numpy as np


def height(x, y):
    return (6.0 * np.sin(x / 97.0) * np.cos(y / 131.0) + 2.5 * np.sin((x + 2.0 * y) / 41.0)
            + 0.8 * np.cos((3.0 * x - y) / 17.0))


def gradient(x, y):
    gx = (6.0 / 97.0 * np.cos(x / 97.0) * np.cos(y / 131.0) + 2.5 / 41.0 * np.cos((x + 2.0 * y) / 41.0)
          - 0.8 * 3.0 / 17.0 * np.sin((3.0 * x - y) / 17.0))
    gy = (-6.0 / 131.0 * np.sin(x / 97.0) * np.sin(y / 131.0) + 5.0 / 41.0 * np.cos((x + 2.0 * y) / 41.0)
          + 0.8 / 17.0 * np.sin((3.0 * x - y) / 17.0))
    return gx, gy


def chunks(a, n, rng):
    """The n points, 2^21 at a time: x, y uniform over the square, z the hills plus noise."""
    chunk = 1 << 21
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        x = rng.uniform(0.0, a.size, m)
        y = rng.uniform(0.0, a.size, m)
        yield x, y, height(x, y) + rng.normal(0.0, a.noise, m)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("output")
    p.add_argument("millions", type=float)
    p.add_argument("--size", type=float, default=2000.0, help="edge of the square, metres")
    p.add_argument("--noise", type=float, default=0.02, help="height noise sigma, metres")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--las", action="store_true", help="a LAS file without normals")
    a = p.parse_args()
    n = int(a.millions * 1e6)
    rng = np.random.default_rng(a.seed)
    if a.las:
        write_las(a, n, rng)
        return
    with open(a.output, "wb") as f:
        f.write(("ply\nformat binary_little_endian 1.0\n"
                 f"comment synthetic terrain, {n} uniform random points over {a.size} m, "
                 f"noise {a.noise} m, seed {a.seed}\n"
                 f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float nx\nproperty float ny\nproperty float nz\nend_header\n").encode())
        for x, y, z in chunks(a, n, rng):
            m = len(x)
            gx, gy = gradient(x, y)
            nrm = np.stack([-gx, -gy, np.ones(m)], axis=1)
            nrm /= np.linalg.norm(nrm, axis=1)[:, None]
            rows = np.concatenate([np.stack([x, y, z], axis=1), nrm], axis=1).astype("<f4")
            f.write(rows.tobytes())


def las_header(n, size, zmin, zmax):
    """A LAS 1.2 public header block (227 bytes) for n points of format 0, scale 0.001."""
    h = bytearray(227)
    h[0:4] = b"LASF"
    h[24], h[25] = 1, 2
    h[26:58] = b"vdbrecon bench/terrain.py".ljust(32, b"\0")
    h[58:90] = b"numpy".ljust(32, b"\0")
    struct.pack_into("<HHHII", h, 90, 1, 2026, 227, 227, 0)  # day, year, header, offset, VLRs
    struct.pack_into("<BHI", h, 104, 0, 20, n)               # format 0, 20-byte records
    struct.pack_into("<5I", h, 111, n, 0, 0, 0, 0)           # points by return
    struct.pack_into("<3d", h, 131, 0.001, 0.001, 0.001)     # scale
    struct.pack_into("<3d", h, 155, 0.0, 0.0, 0.0)           # offset
    struct.pack_into("<6d", h, 179, size, 0.0, size, 0.0, zmax, zmin)
    return bytes(h)


def write_las(a, n, rng):
    rec = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("intensity", "<u2"),
                    ("returns", "u1"), ("cls", "u1"), ("angle", "i1"), ("user", "u1"),
                    ("source", "<u2")])
    with open(a.output, "wb") as f:
        f.write(las_header(n, a.size, -20.0, 20.0))
        for x, y, z in chunks(a, n, rng):
            r = np.zeros(len(x), rec)
            r["x"], r["y"], r["z"] = (np.rint(v * 1000.0) for v in (x, y, z))
            r["returns"] = 0b001001  # return 1 of 1
            r["cls"] = 2
            f.write(r.tobytes())


if __name__ == "__main__":
    main()
