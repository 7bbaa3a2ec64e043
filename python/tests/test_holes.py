"""Mesh hole filling (fill_holes) and reconstruct(watertight=True)."""
import numpy as np

import vdbrecon
from conftest import sphere


def capped_sphere(n=20000, cap=0.8):
    points, normals = sphere(n)
    keep = points[:, 1] < cap
    return points[keep], normals[keep]


def test_fill_holes_closes_a_cut_sphere_and_follows_its_curvature():
    points, normals = sphere(20000)
    mesh = vdbrecon.reconstruct(points, normals, voxel=0.05)
    v = mesh.vertices
    f = mesh.faces
    centroid_y = v[f].mean(axis=1)[:, 1]
    cut = vdbrecon.Mesh(v, f[centroid_y < 0.8])
    assert vdbrecon.mesh_topology(cut).boundary_edges > 20
    r = vdbrecon.fill_holes(cut)
    t = vdbrecon.mesh_topology(r.mesh)
    assert r.loops == r.filled == 1 and r.added_vertices > 10
    assert t.boundary_edges == 0 and t.nonmanifold_edges == 0 and t.euler == 2
    new = r.mesh.vertices[len(v):]
    # a flat patch would sag 0.2 below the cap top; the faired one stays within 0.08
    assert np.abs(np.linalg.norm(new, axis=1) - 1.0).max() < 0.08
    # max_edges below the loop's length leaves it open
    small = vdbrecon.fill_holes(cut, max_edges=5)
    assert small.filled == 0 and small.largest_open > 5


def test_reconstruct_watertight_gives_one_closed_piece_and_its_volume():
    points, normals = capped_sphere()
    open_mesh = vdbrecon.reconstruct(points, normals, voxel=0.05)
    assert vdbrecon.mesh_topology(open_mesh).boundary_edges > 0
    r = vdbrecon.reconstruct(points, normals, voxel=0.05, watertight=True, return_result=True)
    t = vdbrecon.mesh_topology(r.mesh)
    assert t.boundary_edges == 0 and t.nonmanifold_edges == 0 and t.components == 1
    assert r.holes.filled == 1
    assert r.closed_volume is not None and "fill" in r.closed_volume.grids()
    # fill_holes=N: a loop longer than N stays open
    kept_open = vdbrecon.reconstruct(points, normals, voxel=0.05, fill_holes=5)
    assert vdbrecon.mesh_topology(kept_open).boundary_edges > 0
