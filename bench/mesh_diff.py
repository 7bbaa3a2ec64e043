#!/usr/bin/python3
"""Whether two meshes are the same up to the order of vertices and faces: vertex and face
counts, the largest vertex difference after sorting both by position, and whether the faces
(renumbered, each starting at its smallest vertex) are equal. Prints one line.

    PYTHONPATH=build/python bench/mesh_diff.py A.ply B.ply
"""
import sys

import numpy as np

import vdbrecon


def canonical(mesh):
    """(vertices sorted by position, in world units; faces renumbered, each starting at its
    smallest vertex, sorted) of a vdbrecon.Mesh or mesh path."""
    m = vdbrecon.read_mesh(mesh) if not isinstance(mesh, vdbrecon.Mesh) else mesh
    v = np.asarray(m.vertices, np.float64) + np.asarray(m.origin)
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    rank = np.empty(len(v), np.int64)
    rank[order] = np.arange(len(v))
    f = rank[np.asarray(m.faces)]
    k = np.argmin(f, axis=1)
    f = np.stack([f[np.arange(len(f)), (k + i) % 3] for i in range(3)], axis=1)
    return v[order], f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]


def main():
    a, b = canonical(sys.argv[1]), canonical(sys.argv[2])
    if a[0].shape != b[0].shape or a[1].shape != b[1].shape:
        print(f"different counts: {len(a[0])} vs {len(b[0])} vertices, "
              f"{len(a[1])} vs {len(b[1])} faces")
    else:
        same = "equal" if np.array_equal(a[1], b[1]) else "DIFFER"
        print(f"{len(a[0])} vertices, {len(a[1])} faces; largest vertex difference "
              f"{np.abs(a[0] - b[0]).max():.3g}; faces {same}")


if __name__ == "__main__":
    main()
