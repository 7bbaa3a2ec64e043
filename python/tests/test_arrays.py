"""numpy in and out: no copies where none are needed, one conversion where one is, clear errors
for what cannot work."""
import gc
import sys

import numpy as np
import pytest

import vdbrecon
from vdbrecon import _vdbrecon
from conftest import sphere


def address(a):
    return a.__array_interface__["data"][0]


def test_float32_c_contiguous_input_is_not_converted():
    points, _ = sphere(100)
    assert vdbrecon._as_points(points) is points
    assert vdbrecon._as_array(points, "normals", 3) is points


def test_other_layouts_and_dtypes_are_converted_once_to_the_same_result():
    points, normals = sphere(4000)
    ref = vdbrecon.reconstruct(points, normals, voxel=0.1)
    for p in (points.astype(np.float64), np.asfortranarray(points), points.tolist(),
              np.ascontiguousarray(np.hstack([points, points])[:, :3]).astype(">f4")):
        converted = vdbrecon._as_points(p)
        assert converted.dtype == np.float32 and converted.flags.c_contiguous
        m = vdbrecon.reconstruct(p, normals.astype(np.float64), voxel=0.1)
        np.testing.assert_array_equal(m.vertices, ref.vertices)
        np.testing.assert_array_equal(m.faces, ref.faces)
    strided = np.hstack([points, points])[:, ::2]  # a non-contiguous view of other values
    assert vdbrecon._as_points(strided).flags.c_contiguous


def test_output_arrays_are_views_of_the_library_mesh():
    points, normals = sphere(4000)
    mesh = vdbrecon.reconstruct(points, normals, voxel=0.1)
    v1, v2 = mesh.vertices, mesh.vertices
    assert address(v1) == address(v2)  # both views of the same C++ vector, no copy
    assert np.shares_memory(v1, v2)
    assert address(mesh.faces) == address(mesh.faces)
    v1[0, 0] = 42.0
    assert mesh.vertices[0, 0] == 42.0  # writes go to the library's mesh
    faces = mesh.faces
    del mesh, v1, v2
    gc.collect()
    assert faces.shape[1] == 3 and faces.max() > 0  # the view keeps its mesh alive


def test_float32_c_contiguous_input_is_used_without_a_copy():
    points, normals = sphere(4000)
    refs = sys.getrefcount(points)
    cloud = vdbrecon.PointCloud(points, normals)  # borrows both arrays
    assert address(cloud.positions) == address(points)
    assert address(cloud.normals) == address(normals)
    assert sys.getrefcount(points) == refs + 1  # the cloud keeps the array alive
    # The normal stage keeps valid input normals as they are: the result is the input's memory.
    n = vdbrecon.estimate_normals(cloud, scale="none")
    assert n.estimated == 0 and address(n.normals) == address(normals)
    # Converted inputs are converted once, then borrowed.
    c64 = vdbrecon._cloud(points.astype(np.float64))
    assert c64.positions.base is not None and address(c64.positions) != address(points)
    del cloud, n
    gc.collect()
    assert sys.getrefcount(points) == refs  # released with the cloud


def test_borrowed_arrays_outlive_their_python_name_and_survive_reconstruct_unchanged():
    points, normals = sphere(4000)
    expected = points.copy()
    cloud = vdbrecon.PointCloud(points)
    view = cloud.positions
    del points
    gc.collect()  # the cloud still holds the array
    np.testing.assert_array_equal(cloud.positions, expected)
    mesh = vdbrecon.reconstruct(cloud, voxel=0.1)  # estimates normals, removes outliers
    assert len(mesh.faces) > 0
    assert address(cloud.positions) == address(view) and cloud.normals is None  # untouched
    np.testing.assert_array_equal(view, expected)
    with_outliers_off = vdbrecon.reconstruct(cloud, voxel=0.1, outliers_enabled=False)
    assert len(with_outliers_off.faces) > 0
    np.testing.assert_array_equal(cloud.positions, expected)


def test_array_outputs_of_other_stages():
    points, normals = sphere(3000)
    n = vdbrecon.estimate_normals(points, k=8)
    assert n.normals.shape == (3000, 3) and n.normals.dtype == np.float32
    assert address(n.normals) == address(n.normals)
    assert np.abs(np.sum(n.normals * normals, axis=1)).min() > 0.95
    coords, values = vdbrecon.splat(points, normals, voxel=0.1).volume.to_arrays("sdf")
    assert coords.dtype == np.int32 and coords.shape[1] == 3
    assert values.dtype == np.float32 and values.shape == (len(coords),)
    assert type(values.base).__name__ == "PyCapsule"  # adopted, not copied


@pytest.mark.parametrize("bad,error,words", [
    (np.zeros((10, 2), np.float32), ValueError, "(N, 3)"),
    (np.zeros((10, 3, 1), np.float32), ValueError, "(N, 3)"),
    (np.zeros(30, np.float32), ValueError, "(N, 3)"),
    (np.array([["a", "b", "c"]] * 10), TypeError, "real numbers"),
    (np.zeros((10, 3), complex), TypeError, "real numbers"),
    (np.zeros((10, 3), bool), TypeError, "real numbers"),
    ([[1, 2], [3]], TypeError, "array-like"),
    ("points.ply", TypeError, "real numbers"),
])
def test_bad_point_arrays_are_rejected(bad, error, words):
    with pytest.raises(error) as e:
        vdbrecon.reconstruct(bad, voxel=0.1)
    assert words in str(e.value) and "points" in str(e.value)


def test_non_finite_points_are_rejected_naming_the_row():
    points, normals = sphere(100)
    points[17, 1] = np.nan
    with pytest.raises(ValueError, match="row 17"):
        vdbrecon.reconstruct(points, normals, voxel=0.1)


def test_attribute_arrays_must_match_the_points():
    points, normals = sphere(100)
    with pytest.raises(ValueError, match="100 rows"):
        vdbrecon.reconstruct(points, normals[:50], voxel=0.1)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        vdbrecon.reconstruct(points, normals[:, :2], voxel=0.1)


def test_raw_module_takes_only_float32_c_arrays():
    points, _ = sphere(100)
    with pytest.raises(TypeError, match="C-contiguous float32"):
        _vdbrecon.PointCloud(points.astype(np.float64))
    with pytest.raises(TypeError, match="not C-contiguous"):
        _vdbrecon.PointCloud(np.asfortranarray(points))


def test_mesh_from_numpy_borrows_its_arrays_read_only():
    points, normals = sphere(4000)
    ref = vdbrecon.reconstruct(points, normals, voxel=0.1)
    v, f = ref.vertices.copy(), ref.faces.copy()
    refs = sys.getrefcount(v)
    m = vdbrecon.Mesh(v, f)
    assert address(m.vertices) == address(v) and address(m.faces) == address(f)
    assert sys.getrefcount(v) == refs + 1
    assert not m.vertices.flags.writeable  # v is the caller's: the mesh does not write to it
    with pytest.raises(ValueError):
        m.vertices[0, 0] = 1.0
    t = vdbrecon.mesh_topology(m)
    assert t.faces == len(f) and t.boundary_edges == 0
    del v, f
    gc.collect()
    np.testing.assert_array_equal(m.faces, ref.faces)  # kept alive by the mesh
    assert vdbrecon.evaluate(m, ref).hausdorff < 1e-6  # the same surface


def test_mesh_construction_checks_indices():
    v = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="face 1 has vertex index 3"):
        vdbrecon.Mesh(v, np.array([[0, 1, 2], [0, 1, 3]], np.int32))
    with pytest.raises(TypeError, match="int32"):
        vdbrecon.Mesh(v, np.array([[0, 1, 2]], np.int64))
    m = vdbrecon.Mesh(v, np.array([[0, 1, 2]], np.int32))
    assert len(m.faces) == 1 and m.normals is None and m.colors is None


def test_library_errors_map_to_python_exceptions(tmp_path):
    with pytest.raises(vdbrecon.IoError) as e:
        vdbrecon.read_points(tmp_path / "missing.ply")
    assert isinstance(e.value, OSError) and isinstance(e.value, vdbrecon.Error)
    assert "missing.ply" in str(e.value)
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\n"
                   "property float y\nproperty float z\nend_header\n\x00\x00")
    with pytest.raises(vdbrecon.FormatError) as e:
        vdbrecon.read_points(bad)
    assert isinstance(e.value, OSError) and "bad.ply" in str(e.value)
    points, normals = sphere(100)
    with pytest.raises(vdbrecon.InvalidArgument) as e:
        vdbrecon.reconstruct(points, normals, voxel=0.1, k=1)
    assert isinstance(e.value, ValueError) and "normals.k" in str(e.value)
    with pytest.raises(vdbrecon.InvalidArgument, match="voxel_size"):
        vdbrecon.splat(points, normals, voxel=-1.0)
    with pytest.raises(vdbrecon.NumericalError) as e:
        vdbrecon.splat(points, normals, voxel=0.1, min_weight=1e9)  # no voxel that heavy
    assert isinstance(e.value, RuntimeError) and "Hint" in str(e.value)
    with pytest.raises(vdbrecon.NumericalError, match="coincide"):
        vdbrecon.reconstruct(np.zeros((100, 3), np.float32), normals)
    with pytest.raises(vdbrecon.InvalidArgument, match="no normals"):
        vdbrecon.splat(points, voxel=0.1)


def test_las_attributes_come_with_the_points(shared_data):
    path = shared_data / "pdal_autzen" / "autzen_trim.las"
    r = vdbrecon.read_points(path)
    assert r.classification.dtype == np.uint8 and r.intensity.dtype == np.uint16
    assert len(r.classification) == len(r.cloud.positions) == 110000
    assert np.count_nonzero(r.classification == 2) == 26107  # ground (the MANIFEST's count)
    assert np.all((r.return_number >= 1) & (r.return_number <= r.number_of_returns))
    ground = vdbrecon.read_points(path, classes=[2])
    assert np.all(ground.classification == 2) and len(ground.intensity) == 26107
    ply = vdbrecon.read_points(shared_data / "pdal_autzen" / "autzen_trim.ply")
    assert len(ply.classification) == 0
