"""The outlier and closing stages: remove_outliers() and close() on their own, the same stages
inside reconstruct(), their options and results."""
import numpy as np
import pytest

import vdbrecon
from conftest import sphere

VOXEL = 0.05


CAP = 0.985  # the cap y > CAP is 2 sqrt(1 - CAP^2) = 6.9 voxels across


@pytest.fixture(scope="module")
def capped_sphere():
    """A unit sphere (20 voxels radius) of 40000 points with its top cap missing."""
    points, normals = sphere(40000)
    keep = points[:, 1] <= CAP
    return points[keep], normals[keep]


@pytest.fixture(scope="module")
def capped_volume(capped_sphere):
    points, normals = capped_sphere
    return vdbrecon.splat(points, normals, voxel=VOXEL).volume


@pytest.fixture(scope="module")
def strays():
    """20000 sphere points followed by 300 uniform random points in [-1.5, 1.5]^3."""
    points, normals = sphere(20000)
    rng = np.random.default_rng(7)
    extra = rng.uniform(-1.5, 1.5, size=(300, 3)).astype(np.float32)
    return np.concatenate([points, extra]), normals, len(points)


# ---- close ----------------------------------------------------------------------------------


def test_hole_closing_makes_the_capped_sphere_watertight(capped_sphere):
    points, normals = capped_sphere
    open_mesh = vdbrecon.reconstruct(points, normals, voxel=VOXEL)
    assert vdbrecon.mesh_topology(open_mesh).boundary_edges > 0
    too_small = vdbrecon.reconstruct(points, normals, voxel=VOXEL, hole_radius=1)
    assert vdbrecon.mesh_topology(too_small).boundary_edges > 0  # 2R < 6.9 voxels
    r = vdbrecon.reconstruct(points, normals, voxel=VOXEL, hole_radius=4, return_result=True)
    t = vdbrecon.mesh_topology(r.mesh)
    assert t.boundary_edges == 0 and t.nonmanifold_edges == 0 and t.components == 1
    assert t.euler == 2
    # The cap is back where the sphere was.
    top = r.mesh.vertices[r.mesh.vertices[:, 1] > CAP]
    assert len(top) > 10
    assert np.abs(np.linalg.norm(top, axis=1) - 1.0).max() < 0.5 * VOXEL
    # The result carries the closed volume and the closing's statistics.
    assert r.closed_volume is not None and "fill" in r.closed_volume.grids()
    assert "fill" not in r.volume.grids()
    assert 0 < r.close.supported_voxels < r.close.closed_voxels
    assert r.close.filled_voxels > 0
    assert r.close.solid_voxels_before == r.close.solid_voxels_after == 0  # no solid closing
    assert [t.stage for t in r.timings] == ["outliers", "normals", "splat", "close", "mesh",
                                            "clean"]
    # close_hole_radius is the same option under its qualified name.
    again = vdbrecon.reconstruct(points, normals, voxel=VOXEL, close_hole_radius=4)
    np.testing.assert_array_equal(again.faces, r.mesh.faces)


def test_close_on_a_splat_result(capped_volume):
    volume = capped_volume
    c = vdbrecon.close(volume, hole_radius=4)
    assert isinstance(c, vdbrecon.CloseResult)
    closed = c.volume
    assert closed.grids() == ["sdf", "weight", "nearest", "density", "fill"]
    assert volume.grids() == ["sdf", "weight", "nearest", "density"]  # the input is untouched
    assert closed.active_voxels == volume.active_voxels + c.filled_voxels
    fill_coords, fill = closed.to_arrays("fill")
    assert fill.dtype == np.float32 and np.all(fill == 1.0)
    assert len(fill_coords) == c.closed_voxels
    sdf_coords, _ = closed.to_arrays("sdf")
    as_set = {tuple(x) for x in sdf_coords}
    assert all(tuple(x) in as_set for x in fill_coords)  # the fill lies on valid voxels
    # Filled voxels are where the cap was: the extended field is the sphere's distance there.
    world = np.asarray(closed.origin) + closed.voxel_size * sdf_coords
    _, sdf = closed.to_arrays("sdf")
    cap = (world[:, 1] > CAP) & (np.abs(sdf) < VOXEL)
    assert cap.sum() > 10
    err = np.abs(np.linalg.norm(world[cap], axis=1) - 1.0 - sdf[cap])
    assert err.max() < 0.5 * VOXEL
    # Meshing the closed volume: no boundary; the open volume keeps its hole.
    assert vdbrecon.mesh_topology(vdbrecon.extract_mesh(closed).mesh).boundary_edges == 0
    assert vdbrecon.mesh_topology(vdbrecon.extract_mesh(volume).mesh).boundary_edges > 0


def test_close_takes_mesh_options_and_paths(capped_volume, tmp_path):
    a = vdbrecon.close(capped_volume, hole_radius=2)
    b = vdbrecon.close(capped_volume, hole_radius=2, min_surface_weight=1e9)
    assert b.supported_voxels == 0 < a.supported_voxels  # the trim reached MeshOptions
    c = vdbrecon.close(capped_volume, close_hole_radius=2, mesh_max_gap=0.1)
    assert 0 < c.supported_voxels < a.supported_voxels
    path = tmp_path / "capped.vdb"
    vdbrecon.write_volume(path, capped_volume)
    from_file = vdbrecon.close(path, hole_radius=2)  # a .vdb path works like a Volume
    assert from_file.closed_voxels == a.closed_voxels
    unchanged = vdbrecon.close(capped_volume, hole_radius=0, solid_radius=0)  # explicit zeros
    assert unchanged.volume.grids() == capped_volume.grids()
    assert unchanged.volume.active_voxels == capped_volume.active_voxels
    with pytest.raises(TypeError, match="hole_radius=R and/or solid_radius=R"):
        vdbrecon.close(capped_volume)
    with pytest.raises(TypeError, match="same option"):
        vdbrecon.close(capped_volume, hole_radius=2, close_hole_radius=2)
    with pytest.raises(TypeError, match="unexpected keyword argument 'radius'.*hole_radius"):
        vdbrecon.close(capped_volume, radius=2)


def test_solid_closing(capped_volume):
    points, normals = sphere(20000)
    volume = vdbrecon.splat(points, normals, voxel=VOXEL).volume
    c = vdbrecon.close(volume, solid_radius=2)
    assert "fill" in c.volume.grids()
    # A convex sphere has no concavity: the inside keeps its volume (4/3 pi / voxel^3).
    inside = 4.0 / 3.0 * np.pi / VOXEL ** 3
    assert c.solid_voxels_before == pytest.approx(inside, rel=0.02)
    assert c.solid_voxels_after == pytest.approx(c.solid_voxels_before, rel=0.02)
    t = vdbrecon.mesh_topology(vdbrecon.extract_mesh(c.volume).mesh)
    assert t.watertight() and t.signed_volume == pytest.approx(4.0 / 3.0 * np.pi, rel=0.02)
    with pytest.raises(vdbrecon.NumericalError, match="open"):
        vdbrecon.close(capped_volume, solid_radius=2)  # needs a watertight surface


def test_fill_survives_files_and_arrays(capped_volume, tmp_path):
    closed = vdbrecon.close(capped_volume, hole_radius=4).volume
    path = tmp_path / "closed.vdb"
    vdbrecon.write_volume(path, closed)
    back = vdbrecon.read_volume(path)
    assert back.grids() == closed.grids()
    for grid in ("fill", "sdf"):
        np.testing.assert_array_equal(back.to_arrays(grid)[0], closed.to_arrays(grid)[0])
    coords, sdf = closed.to_arrays("sdf")
    rebuilt = vdbrecon.Volume.from_arrays(
        coords, sdf, voxel_size=closed.voxel_size, origin=closed.origin,
        fill=closed.to_arrays("fill")[0], background=closed.background)
    assert rebuilt.grids() == ["sdf", "density", "fill"]
    np.testing.assert_array_equal(rebuilt.to_arrays("fill")[0], closed.to_arrays("fill")[0])
    # Without weight and nearest nothing is trimmed, with or without the fill.
    assert vdbrecon.mesh_topology(vdbrecon.extract_mesh(rebuilt).mesh).boundary_edges == 0
    with pytest.raises(TypeError, match="fill: expected a C-contiguous int32"):
        vdbrecon.Volume.from_arrays(coords, sdf, voxel_size=0.1, fill=coords.astype(np.int64))


def test_stage_by_stage_equals_reconstruct_with_closing(capped_sphere):
    points, normals = capped_sphere
    ref = vdbrecon.reconstruct(points, normals, voxel=VOXEL, hole_radius=3, max_gap=2.0)
    cloud = vdbrecon.remove_outliers(points, normals).cloud
    n = vdbrecon.estimate_normals(cloud)
    volume = vdbrecon.splat(cloud, n.normals, scales=n.scales, voxel=VOXEL).volume
    closed = vdbrecon.close(volume, hole_radius=3, max_gap=2.0).volume
    mesh = vdbrecon.clean_mesh(vdbrecon.extract_mesh(closed, max_gap=2.0).mesh).mesh
    np.testing.assert_array_equal(mesh.faces, ref.faces)
    np.testing.assert_array_equal(mesh.vertices, ref.vertices)


# ---- outliers -------------------------------------------------------------------------------


def stray_distance(points, n_sphere):
    return np.abs(np.linalg.norm(points[n_sphere:], axis=1) - 1.0)


def test_remove_outliers_drops_strays_and_keeps_the_sphere(strays):
    points, normals, n_sphere = strays
    r = vdbrecon.remove_outliers(points)
    assert isinstance(r, vdbrecon.OutlierResult)
    removed = r.removed
    assert removed.dtype == np.bool_ and removed.shape == (len(points),)
    assert not removed[:n_sphere].any()  # no sphere point
    far = stray_distance(points, n_sphere) > 0.1
    assert far.sum() > 200
    assert removed[n_sphere:][far].mean() > 0.85
    # Counts add up, and the cloud holds the kept points in input order.
    assert r.statistical + r.planarity == removed.sum() > 0
    assert r.statistical > 0
    assert len(r.cloud) == len(points) - removed.sum()
    np.testing.assert_array_equal(r.cloud.positions, points[~removed])


def test_remove_outliers_filters_attributes_along(strays):
    points, normals, n_sphere = strays
    all_normals = np.concatenate([normals, np.tile([[0.0, 0.0, 1.0]], (len(points) - n_sphere,
                                                                     1))]).astype(np.float32)
    colors = np.linspace(0, 1, 3 * len(points), dtype=np.float32).reshape(-1, 3)
    r = vdbrecon.remove_outliers(points, all_normals, colors)
    keep = ~r.removed
    np.testing.assert_array_equal(r.cloud.normals, all_normals[keep])
    np.testing.assert_array_equal(r.cloud.colors, colors[keep])
    cloud = vdbrecon.PointCloud(points, all_normals)  # a PointCloud works too
    again = vdbrecon.remove_outliers(cloud)
    np.testing.assert_array_equal(again.removed, r.removed)


def test_remove_outliers_options(strays):
    points, _, n_sphere = strays
    default = vdbrecon.remove_outliers(points)
    off = vdbrecon.remove_outliers(points, enabled=False)  # only an explicit False skips it
    assert not off.removed.any() and len(off.cloud) == len(points)
    assert off.statistical == off.planarity == 0
    statistical_only = vdbrecon.remove_outliers(points, planarity_ratio=0.0)
    assert statistical_only.planarity == 0
    assert statistical_only.statistical == default.statistical
    planarity_only = vdbrecon.remove_outliers(points, statistical_ratio=0.0)
    assert planarity_only.statistical == 0 and planarity_only.planarity > 0
    assert planarity_only.removed.sum() == planarity_only.planarity
    few = vdbrecon.remove_outliers(points[:10])  # fewer than k + 1 points: nothing removed
    assert few.removed.shape == (10,) and not few.removed.any()


def test_reconstruct_removes_outliers_first(strays):
    points, normals, n_sphere = strays
    r = vdbrecon.reconstruct(points, voxel=VOXEL, return_result=True)
    alone = vdbrecon.remove_outliers(points)
    np.testing.assert_array_equal(r.outliers.removed, alone.removed)
    assert (r.outliers.statistical, r.outliers.planarity) == (alone.statistical,
                                                              alone.planarity)
    assert len(r.outliers.cloud) == 0  # moved into the pipeline
    assert r.timings[0].stage == "outliers"
    off = vdbrecon.reconstruct(points, voxel=VOXEL, outliers_enabled=False, return_result=True)
    assert off.outliers.removed.shape == (0,) and "outliers" not in [t.stage for t in off.timings]
    assert off.closed_volume is None and off.close.closed_voxels == 0
    # Strays splatted into the volume give extra pieces: more components before cleanup.
    assert off.clean_stats.components_before > r.clean_stats.components_before
    k = vdbrecon.reconstruct(points, voxel=VOXEL, outliers_k=8, statistical_ratio=2.0,
                             return_result=True)
    assert k.outliers.removed.sum() == vdbrecon.remove_outliers(
        points, k=8, statistical_ratio=2.0).removed.sum()


def test_reconstruct_leaves_the_cloud_and_its_views_intact(strays):
    points, _, _ = strays
    cloud = vdbrecon.PointCloud(points)
    view = cloud.positions
    address = view.__array_interface__["data"][0]
    r = vdbrecon.reconstruct(cloud, voxel=VOXEL, return_result=True)
    assert r.outliers.removed.sum() > 0  # the pipeline dropped points ...
    assert len(cloud) == len(points) and cloud.normals is None  # ... not from this cloud
    assert cloud.positions.__array_interface__["data"][0] == address
    np.testing.assert_array_equal(view, points)


# ---- options --------------------------------------------------------------------------------


def test_new_options_map_to_their_struct():
    names = vdbrecon._RECONSTRUCT_NAMES
    assert names["k"] == ("normals", "k")  # like the CLI's --k
    assert names["normals_k"] == ("normals", "k") and names["outliers_k"] == ("outliers", "k")
    assert "enabled" not in names and names["outliers_enabled"] == ("outliers", "enabled")
    assert names["statistical_ratio"] == ("outliers", "statistical_ratio")
    assert names["hole_radius"] == ("close", "hole_radius")
    assert names["solid_radius"] == names["close_solid_radius"] == ("close", "solid_radius")
    o = vdbrecon._fill_pipeline(names, {"k": 9, "outliers_k": 20, "solid_radius": 3,
                                        "outliers_enabled": False}, "t")
    assert o.normals.k == 9 and o.outliers.k == 20 and o.close.solid_radius == 3
    assert o.outliers.enabled is False and o.close.hole_radius == 0
    assert vdbrecon._RUN_NAMES["hole_radius"] == ("close", "hole_radius")
    assert vdbrecon._CLOSE_NAMES["max_gap"] == vdbrecon._CLOSE_NAMES["mesh_max_gap"] == (
        "mesh", "max_gap")


def test_new_options_are_documented_with_defaults():
    d = vdbrecon.PipelineOptions()
    assert d.outliers == vdbrecon.OutlierOptions() and d.outliers.enabled is True
    assert d.close == vdbrecon.CloseOptions() and not d.close.enabled()
    text = vdbrecon.reconstruct.__doc__
    assert f"outliers_k = {d.outliers.k!r}" in text and f"k = {d.normals.k!r}" in text
    assert "hole_radius = 0" in text and "CLI --close)" in text and "CLI --close-solid)" in text
    assert "outliers_enabled = True" in text and "--no-outliers" in text
    order = [text.index(s) for s in ("OutlierOptions:", "NormalOptions:", "SplatOptions:",
                                     "CloseOptions:", "MeshOptions:", "CleanOptions:")]
    assert order == sorted(order)  # grouped in pipeline order
    import inspect
    sig = inspect.signature(vdbrecon.remove_outliers)
    assert list(sig.parameters)[:3] == ["points", "normals", "colors"]
    assert sig.parameters["enabled"].default is True
    assert sig.parameters["k"].default == vdbrecon.OutlierOptions().k
    sig = inspect.signature(vdbrecon.close)
    assert sig.parameters["hole_radius"].default == 0
    assert sig.parameters["max_gap"].default == vdbrecon.MeshOptions().max_gap
    assert "CloseOptions:" in vdbrecon.close.__doc__ and "MeshOptions:" in vdbrecon.close.__doc__
    for cls in (vdbrecon.OutlierOptions, vdbrecon.CloseOptions):
        for name, doc in cls._fields:
            assert hasattr(cls(), name) and len(doc) > 10, (cls, name)
    assert vdbrecon.OutlierResult.removed.__doc__ and vdbrecon.CloseResult.volume.__doc__
    assert "outliers > normals > splat > close > mesh > clean" in \
        vdbrecon._vdbrecon.reconstruct.__doc__


@pytest.mark.parametrize("call,field", [
    (lambda p, v: vdbrecon.remove_outliers(p, k=2), "outliers.k"),
    (lambda p, v: vdbrecon.remove_outliers(p, planarity_ratio=1.0), "outliers.planarity_ratio"),
    (lambda p, v: vdbrecon.remove_outliers(p, statistical_ratio=0.5),
     "outliers.statistical_ratio"),
    (lambda p, v: vdbrecon.remove_outliers(p, planarity_spacing=-1.0),
     "outliers.planarity_spacing"),
    (lambda p, v: vdbrecon.close(v, hole_radius=-1), "close.hole_radius"),
    (lambda p, v: vdbrecon.close(v, solid_radius=65), "close.solid_radius"),
    (lambda p, v: vdbrecon.close(v, hole_radius=2, max_gap=-1.0), "max_gap"),
    (lambda p, v: vdbrecon.reconstruct(p, voxel=VOXEL, hole_radius=65), "close.hole_radius"),
    (lambda p, v: vdbrecon.reconstruct(p, voxel=VOXEL, outliers_k=1), "outliers.k"),
    (lambda p, v: vdbrecon.reconstruct(p, voxel=VOXEL, outliers_enabled=False,
                                       statistical_ratio=0.5), "outliers.statistical_ratio"),
])
def test_out_of_range_options_raise_invalid_argument(call, field, capped_volume):
    points, _ = sphere(500)
    with pytest.raises(vdbrecon.InvalidArgument, match=field) as e:
        call(points, capped_volume)
    assert isinstance(e.value, ValueError)


def test_option_structs_validate_and_compare():
    o = vdbrecon.CloseOptions()
    o.hole_radius = 3
    assert o.enabled() and o != vdbrecon.CloseOptions() and "hole_radius=3" in repr(o)
    o.validate()
    o.solid_radius = -2
    with pytest.raises(vdbrecon.InvalidArgument, match="close.solid_radius"):
        o.validate()
    p = vdbrecon.PipelineOptions()
    p.outliers.k = 30  # nested structs are references
    assert p.outliers.k == 30 and p != vdbrecon.PipelineOptions()
    p.outliers.k = 1
    with pytest.raises(vdbrecon.InvalidArgument, match="outliers.k"):
        p.validate()
    with pytest.raises(TypeError, match="'hole_radius' expects int"):
        vdbrecon.reconstruct(sphere(100)[0], hole_radius=1.5)
