"""Options: same names and defaults as the C++ structs and the CLI; unknown or ill-typed ones
are refused with a message that lists what is valid."""
import inspect
import pydoc
import re
import subprocess

import numpy as np
import pytest

import vdbrecon
from conftest import sphere

# CLI flag -> (options struct class, field)
CLI_FLAGS = {
    "--sigma": (vdbrecon.SplatOptions, "scale_factor"),
    "--sigma-voxels": (vdbrecon.SplatOptions, "sigma_voxels"),
    "--min-sigma": (vdbrecon.SplatOptions, "min_sigma_voxels"),
    "--max-sigma": (vdbrecon.SplatOptions, "max_sigma_voxels"),
    "--support": (vdbrecon.SplatOptions, "support"),
    "--min-weight": (vdbrecon.SplatOptions, "min_weight"),
    "--surface-weight": (vdbrecon.MeshOptions, "min_surface_weight"),
    "--max-gap": (vdbrecon.MeshOptions, "max_gap"),
    "--normals": (vdbrecon.NormalOptions, "mode"),
    "--k": (vdbrecon.NormalOptions, "k"),
    "--orient": (vdbrecon.NormalOptions, "orient"),
    "--min-samples": (vdbrecon.CleanOptions, "min_component_samples"),
    "--min-component": (vdbrecon.CleanOptions, "min_component_ratio"),
    "--scale": (vdbrecon.NormalOptions, "scale"),
    "--mesher": (vdbrecon.MeshOptions, "method"),
    "--adaptivity": (vdbrecon.MeshOptions, "adaptivity"),
    "--threads": (vdbrecon.PipelineOptions, "threads"),
    "--samples": (vdbrecon.EvalOptions, "samples"),
    "--outliers": (vdbrecon.OutlierOptions, "enabled"),
    "--close": (vdbrecon.CloseOptions, "hole_radius"),
    "--close-solid": (vdbrecon.CloseOptions, "solid_radius"),
    "--fill-holes": (vdbrecon.PipelineOptions, "fill_holes"),
    "--watertight": (vdbrecon.PipelineOptions, "watertight"),
    "--tile": (vdbrecon.PipelineOptions, "tile"),
    "--stream": (vdbrecon.PipelineOptions, "stream"),
    "--planes": (vdbrecon.PlaneOptions, "enabled"),
    "--plane-angle": (vdbrecon.PlaneOptions, "angle"),
    "--plane-distance": (vdbrecon.PlaneOptions, "distance"),
    "--plane-min-area": (vdbrecon.PlaneOptions, "min_area"),
}


def cli_help_entries(out):
    """Flag -> (text, the last [default] of its entry) from the CLI's help; an entry is a line
    starting with '  -' and its indented continuation lines."""
    entries = []
    for line in out.splitlines():
        if line.startswith("  -"):
            entries.append(line.strip())
        elif entries and entries[-1] is not None and re.match(r"^ {10,}\S", line):
            entries[-1] += " " + line.strip()
        else:
            entries.append(None)
    found = {}
    for entry in filter(None, entries):
        m = re.match(r"^(--[\w-]+)(?:, --[\w-]+)*(?: \S+)?\s+(.*)\[([^\]]*)\]$", entry)
        if m:
            found[m.group(1)] = (m.group(2), m.group(3))
    return found


def test_defaults_and_choices_agree_with_the_cli_help(cli):
    out = subprocess.run([cli, "--help"], capture_output=True, text=True, check=True).stdout
    found = cli_help_entries(out)
    assert set(CLI_FLAGS) <= set(found), set(CLI_FLAGS) - set(found)
    for flag, (cls, field) in CLI_FLAGS.items():
        text, default = found[flag]
        value = getattr(cls(), field)
        if field in cls._choices:
            assert value == default, flag
            assert "|".join(cls._choices[field]) in text, flag
        elif isinstance(value, bool):  # --x, --no-x [on|off]
            assert default in ("on", "off") and value == (default == "on"), flag
        else:  # "[0: off]" -> 0
            assert float(default.split(":")[0]) == pytest.approx(float(value)), flag
    assert f"k={vdbrecon.OutlierOptions().k})" in found["--outliers"][0]


def test_every_field_has_a_documented_unit_or_meaning():
    for cls in (vdbrecon.ReadOptions, vdbrecon.WriteOptions, vdbrecon.OutlierOptions,
                vdbrecon.NormalOptions, vdbrecon.SplatOptions, vdbrecon.CloseOptions,
                vdbrecon.MeshOptions, vdbrecon.CleanOptions, vdbrecon.HoleFillOptions,
                vdbrecon.EvalOptions, vdbrecon.PlaneOptions,
                vdbrecon.PipelineOptions):
        assert cls._fields, cls
        for name, doc in cls._fields:
            assert hasattr(cls(), name) and len(doc) > 10, (cls, name)


def test_help_shows_options_with_units_and_defaults():
    text = pydoc.render_doc(vdbrecon.reconstruct, renderer=pydoc.plaintext)
    d = vdbrecon.PipelineOptions()
    assert f"min_weight = {d.splat.min_weight!r}" in text
    assert f"k = {d.normals.k!r}" in text
    assert "method = 'dual'  ('dual' | 'vdb' | 'mc' | 'dc')" in text
    assert "voxels" in text and "world units" in text
    sig = inspect.signature(vdbrecon.reconstruct)
    assert list(sig.parameters)[:3] == ["points", "normals", "colors"]
    assert sig.parameters["voxel"].kind is inspect.Parameter.KEYWORD_ONLY
    assert sig.parameters["support"].default == d.splat.support
    assert sig.parameters["mesh_normals"].default is True
    for f in (vdbrecon.read_points, vdbrecon.remove_outliers, vdbrecon.estimate_normals,
              vdbrecon.splat, vdbrecon.close, vdbrecon.extract_mesh, vdbrecon.clean_mesh,
              vdbrecon.evaluate, vdbrecon.write_mesh, vdbrecon.run):
        assert "Options" in f.__doc__, f.__name__
    assert vdbrecon.Volume.to_arrays.__doc__ and vdbrecon.Mesh.vertices.__doc__


def test_defaults_follow_the_structs_not_copies():
    d = vdbrecon.MeshOptions()
    sig = inspect.signature(vdbrecon.extract_mesh)
    for name, _ in vdbrecon.MeshOptions._fields:
        assert sig.parameters[name].default == getattr(d, name)


def test_unknown_option_lists_the_valid_ones():
    points, normals = sphere(100)
    with pytest.raises(TypeError) as e:
        vdbrecon.reconstruct(points, normals, voxel=0.1, sigmaa=2)
    assert "'sigmaa'" in str(e.value) and "scale_factor" in str(e.value)
    assert "mesh_normals" in str(e.value)
    with pytest.raises(TypeError, match="valid options: .*k.*mode"):
        vdbrecon.estimate_normals(points, voxel=0.1)
    with pytest.raises(TypeError, match="unexpected keyword argument 'encoding'"):
        vdbrecon.reconstruct(points, normals, encoding="ascii")  # run()/write_mesh only


def test_bad_values():
    points, normals = sphere(100)
    with pytest.raises(ValueError, match="'xx' is not one of 'dual', 'vdb', 'mc', 'dc'"):
        vdbrecon.reconstruct(points, normals, voxel=0.1, method="xx")
    with pytest.raises(TypeError, match="'k' expects int"):
        vdbrecon.reconstruct(points, normals, voxel=0.1, k="ten")
    with pytest.raises(TypeError, match="expected a string"):
        vdbrecon.reconstruct(points, normals, voxel=0.1, mode=1)
    with pytest.raises(TypeError, match="voxel or voxel_size"):
        vdbrecon.reconstruct(points, normals, voxel=0.1, voxel_size=0.1)
    with pytest.raises(TypeError, match="set the same option"):
        vdbrecon.reconstruct(points, normals, min_weight=0.1, splat_min_weight=0.1)


def test_nested_names_map_to_their_struct():
    names = vdbrecon._RECONSTRUCT_NAMES
    assert names["min_weight"] == ("splat", "min_weight")
    assert names["method"] == ("mesh", "method")
    assert names["mode"] == ("normals", "mode")
    assert names["threads"] == (None, "threads")
    assert "normals" not in names and names["mesh_normals"] == ("mesh", "normals")
    o = vdbrecon._fill_pipeline(names, {"min_weight": 0.5, "method": "mc", "viewpoint": (0, 0, 5),
                                        "k": 12, "mesh_normals": False}, "t")
    assert o.splat.min_weight == 0.5 and o.mesh.method == "mc" and o.normals.k == 12
    assert tuple(o.normals.viewpoint) == (0.0, 0.0, 5.0) and o.mesh.normals is False
    assert o.mesh.max_gap == vdbrecon.MeshOptions().max_gap  # the rest stays at the defaults
    run_names = vdbrecon._RUN_NAMES
    assert run_names["encoding"] == ("write", "encoding")
    assert run_names["non_finite"] == ("read", "non_finite")


def test_options_structs_are_plain_values():
    o = vdbrecon.SplatOptions()
    o.voxel_size = 0.1
    o.min_weight = 0.2
    assert o != vdbrecon.SplatOptions() and "min_weight=0.2" in repr(o)
    o.min_weight = -1.0
    with pytest.raises(vdbrecon.InvalidArgument, match="min_weight"):
        o.validate()
    p = vdbrecon.PipelineOptions()
    p.splat.support = 2.0  # nested structs are references, not copies
    assert p.splat.support == 2.0


def test_knn_backend_for_both_neighbour_stages():
    # Estimated normals on a sphere with copies of a tenth of its points: FLANN's kd-tree gives
    # the grid's lists (ties by index), so the same mesh; the choice reaches both stages.
    points, _ = sphere(8000, 1.0)
    points = np.concatenate([points, points[::10]])
    meshes = [vdbrecon.reconstruct(points, voxel=0.08, knn=b) for b in ("grid", "flann")]
    assert len(meshes[0].faces) > 1000
    assert np.array_equal(meshes[0].vertices, meshes[1].vertices)
    assert np.array_equal(meshes[0].faces, meshes[1].faces)
    assert "knn_eps" in vdbrecon.reconstruct.__doc__ and "knn" in vdbrecon.run.__doc__
    # The stages alone take it too.
    kept = [vdbrecon.remove_outliers(points, knn=b).removed for b in ("grid", "flann")]
    assert np.array_equal(kept[0], kept[1])
    normals = [vdbrecon.estimate_normals(points, knn=b).normals for b in ("grid", "flann")]
    assert np.array_equal(normals[0], normals[1])
    with pytest.raises(TypeError, match="knn_eps"):
        vdbrecon.remove_outliers(points, knn_epsilon=0.5)
    assert vdbrecon.KnnOptions().backend == "grid"
    o = vdbrecon.NormalOptions()
    o.knn.backend = "flann"
    o.knn.eps = 0.5
    assert (o.knn.backend, o.knn.eps) == ("flann", 0.5)
    with pytest.raises(ValueError, match="'kdtree' is not one of 'grid', 'flann'"):
        vdbrecon.reconstruct(points, voxel=0.08, knn="kdtree")
