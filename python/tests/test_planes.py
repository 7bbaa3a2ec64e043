"""planar_regions(): a subdivided box comes out as six planar regions with few faces; the
pipeline's planes_enabled=True gives every face its region, written as the PLY face property
`region` and read back."""
import numpy as np
import pytest

import vdbrecon


def subdivided_box(n=12):
    """A closed unit cube whose faces are n x n quads split in two triangles."""
    verts, faces = [], []
    index = {}

    def vertex(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    for axis in range(3):
        for side in (0.0, 1.0):
            u, w = [a for a in range(3) if a != axis]
            for i in range(n):
                for j in range(n):
                    q = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis], p[u], p[w] = side, (i + di) / n, (j + dj) / n
                        q.append(vertex(p))
                    # counter-clockwise seen from outside
                    outward = (side == 1.0) == ((axis + 1) % 3 == u)
                    a, b, c, d = q if outward else q[::-1]
                    faces += [(a, b, c), (a, c, d)]
    return np.array(verts, np.float32), np.array(faces, np.int32)


def test_box_gives_six_planes_and_few_faces():
    v, f = subdivided_box()
    r = vdbrecon.planar_regions(vdbrecon.Mesh(v, f), voxel=0.05)
    assert len(r.planes) == 6
    normals = np.array([p.normal for p in r.planes])
    assert np.allclose(np.sort(np.abs(normals).max(axis=1)), 1.0, atol=1e-9)
    assert r.faces_before == len(f) and r.faces_after <= len(f) // 10
    assert sorted(set(r.mesh.regions.tolist())) == list(range(6))
    t = vdbrecon.mesh_topology(r.mesh)
    assert t.boundary_edges == 0 and t.components == 1 and t.euler == 2


def test_mesh_distances_are_the_distances_to_a_box():
    v, f = subdivided_box(4)
    box = vdbrecon.Mesh(v, f)
    points = np.array([[0.5, 0.5, 2.0], [0.5, 0.5, 0.4], [2.0, 2.0, 0.5], [0.25, 1.0, 0.75]],
                      np.float32)
    d, face = vdbrecon.mesh_distances(box, points)
    assert d.dtype == np.float64 and face.dtype == np.int32 and len(face) == 4
    assert np.allclose(d, [1.0, 0.4, np.sqrt(2.0), 0.0], atol=1e-6)
    # The closest face of the first point is on the top (z = 1), of the second on the bottom.
    tops = v[f[face]][:, :, 2]
    assert np.all(tops[0] == 1.0) and np.all(tops[1] == 0.0)


def test_pipeline_writes_regions_as_a_face_property(tmp_path):
    rng = np.random.default_rng(2)
    # A box sampled at random, exact normals.
    axis = rng.integers(0, 3, 40000)
    side = rng.integers(0, 2, 40000).astype(np.float32)
    p = rng.random((40000, 3), dtype=np.float32)
    p[np.arange(40000), axis] = side
    n = np.zeros_like(p)
    n[np.arange(40000), axis] = 2.0 * side - 1.0
    src = tmp_path / "box.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(p, normals=n))
    r = vdbrecon.run(src, tmp_path / "box.recon.ply", voxel=0.02, planes_enabled=True, method="dc")
    assert len(r.result.planes.planes) == 6
    header = (tmp_path / "box.recon.ply").read_bytes().split(b"end_header")[0]
    assert b"property int region" in header
    m = vdbrecon.read_mesh(tmp_path / "box.recon.ply")
    assert len(m.faces) == r.result.planes.faces_after


def _planes_points():
    """bench/planes_points.py: the benchmark's measure of the regions' points."""
    import importlib.util
    from conftest import SOURCE_DIR
    spec = importlib.util.spec_from_file_location("planes_points",
                                                  SOURCE_DIR / "bench" / "planes_points.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# The worst region on Autzen is a roof of 102 square voxels (large from 100) whose points the
# planar mesh keeps within half a voxel for 98.1 % (14 of 730 points 0.5-0.74 voxel off; the
# vdb mesher's planar mesh leaves them as far, 98.9 %): a small, slightly tilted roof is
# flattened a little. The room's regions stay at 99 % or more.
@pytest.mark.parametrize("scan, voxel, worst_region", [("pcl_laser/room_scan1.ply", 0.1, 0.99),
                                                       ("pdal_autzen/autzen_trim.ply", 4.4, 0.98)])
def test_room_and_buildings_come_out_ten_times_lighter(shared_data, scan, voxel, worst_region):
    """Issue 25: on room and building scans --planes gives >= 10x fewer faces, the points of
    every large planar region (inliers of its plane that the plain mesh represents) within
    half a voxel of the mesh, and no new holes (same pieces, same Euler characteristic)."""
    points = vdbrecon.read_points(shared_data / scan).cloud
    plain = vdbrecon.reconstruct(points, voxel=voxel)
    planar = vdbrecon.reconstruct(points, voxel=voxel, planes_enabled=True)
    assert len(planar.faces) * 10 <= len(plain.faces)
    before, after = vdbrecon.mesh_topology(plain), vdbrecon.mesh_topology(planar)
    assert (after.components, after.euler) == (before.components, before.euler)
    assert after.boundary_edges < before.boundary_edges
    pp = _planes_points()
    ours, label, count = pp.region_points(np.asarray(points.positions), plain, voxel)
    assert len(np.unique(label)) >= 5 and len(ours) > 0.4 * len(points.positions)
    _, within, worst, _ = pp.coverage(planar, ours, label, count, voxel)
    assert within >= 0.995 and worst >= worst_region, (within, worst)
