#!/usr/bin/python3
"""A synthetic terrain as a binary PLY with exact normals: N million points drawn uniformly at
random over a square of `size` metres, z = rolling hills (a sum of waves) plus Gaussian noise,
normals from the surface's analytic gradient. For the tiled benchmark (bench/tiles.sh).

    bench/terrain.py OUT.ply MILLIONS [--size 2000] [--noise 0.02] [--seed 1]
"""
import argparse

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


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("output")
    p.add_argument("millions", type=float)
    p.add_argument("--size", type=float, default=2000.0, help="edge of the square, metres")
    p.add_argument("--noise", type=float, default=0.02, help="height noise sigma, metres")
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args()
    n = int(a.millions * 1e6)
    rng = np.random.default_rng(a.seed)
    with open(a.output, "wb") as f:
        f.write(("ply\nformat binary_little_endian 1.0\n"
                 f"comment synthetic terrain, {n} uniform random points over {a.size} m, "
                 f"noise {a.noise} m, seed {a.seed}\n"
                 f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float nx\nproperty float ny\nproperty float nz\nend_header\n").encode())
        chunk = 1 << 21
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            x = rng.uniform(0.0, a.size, m)
            y = rng.uniform(0.0, a.size, m)
            z = height(x, y) + rng.normal(0.0, a.noise, m)
            gx, gy = gradient(x, y)
            nrm = np.stack([-gx, -gy, np.ones(m)], axis=1)
            nrm /= np.linalg.norm(nrm, axis=1)[:, None]
            rows = np.concatenate([np.stack([x, y, z], axis=1), nrm], axis=1).astype("<f4")
            f.write(rows.tobytes())


if __name__ == "__main__":
    main()
