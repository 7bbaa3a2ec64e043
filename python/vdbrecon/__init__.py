"""vdbrecon: surface reconstruction from point clouds on sparse OpenVDB grids.

    import numpy as np, vdbrecon
    mesh = vdbrecon.reconstruct(points, normals, voxel=0.002)      # (N, 3) arrays in
    mesh.vertices, mesh.faces                                      # (V, 3) float32, (F, 3) int32

Stage by stage, with the same option names and defaults as the C++ structs and the CLI:

    cloud = vdbrecon.remove_outliers(vdbrecon.read_points("scan.ply").cloud).cloud
    n = vdbrecon.estimate_normals(cloud, k=12)
    volume = vdbrecon.splat(cloud.positions, n.normals, scales=n.scales, voxel=0.002).volume
    closed = vdbrecon.close(volume, hole_radius=3).volume           # optional
    mesh = vdbrecon.clean_mesh(vdbrecon.extract_mesh(closed, method="mc").mesh).mesh
    vdbrecon.write_mesh("scan.mesh.ply", mesh)
    vdbrecon.write_volume("scan.splat.vdb", volume)

Arrays: (N, 3) C-contiguous float32 inputs are used as they are, without a copy (the point cloud
borrows them and keeps them alive); other real dtypes and layouts are converted once; anything
else raises TypeError (wrong kind) or ValueError (wrong shape, non-finite positions). Outputs
are numpy views of the library's arrays (no copy) that keep their owner alive.

Volumes cross as .vdb paths (read_volume / write_volume), as numpy arrays of active voxels
(Volume.to_arrays / Volume.from_arrays), or, when pyopenvdb is importable, as pyopenvdb grids
(to_pyopenvdb / from_pyopenvdb).

Errors: vdbrecon.Error and its subclasses IoError and FormatError (OSError), InvalidArgument
(ValueError) and NumericalError (RuntimeError). Library messages go to the logger "vdbrecon".
The GIL is released while the library works.
"""

import inspect as _inspect
import os as _os
import shutil as _shutil
import tempfile as _tempfile
import textwrap as _textwrap

import numpy as _np

try:
    from . import _vdbrecon as _v
except ImportError as _e:  # e.g. the source tree's python/vdbrecon shadowing the built package
    raise ImportError(f"vdbrecon: the compiled module _vdbrecon is not next to {__file__} "
                      f"({_e}). Build with -DVDBRECON_BUILD_PYTHON=ON and put <build>/python on "
                      "PYTHONPATH, or `cmake --install` it.") from None
from ._vdbrecon import (  # noqa: F401  (re-exported)
    CleanOptions,
    CleanResult,
    CloseOptions,
    DepthOptions,
    CloseResult,
    DecimateOptions,
    PlaneOptions,
    Plane,
    PlaneResult,
    DecimateResult,
    Error,
    EvalOptions,
    EvalResult,
    FormatError,
    FScore,
    HoleFillOptions,
    HoleFillResult,
    InvalidArgument,
    IoError,
    KnnOptions,
    Mesh,
    MeshOptions,
    MeshResult,
    NormalOptions,
    NormalResult,
    NumericalError,
    OutlierOptions,
    OutlierResult,
    PipelineOptions,
    PipelineResult,
    PointCloud,
    ReadOptions,
    ReadResult,
    RunResult,
    SplatOptions,
    SplatResult,
    StageTiming,
    TextureAtlas,
    TextureOptions,
    TopologyStats,
    Volume,
    WriteOptions,
    stage_volume_path,
    version,
)

__version__ = _v.__version__

__all__ = [
    "reconstruct", "run", "Fusion", "DepthOptions", "read_points", "read_mesh", "write_mesh", "write_points",
    "remove_outliers", "estimate_normals", "splat", "close", "extract_mesh", "clean_mesh",
    "fill_holes", "decimate", "DecimateOptions", "DecimateResult", "planar_regions", "PlaneOptions", "PlaneResult", "Plane",
    "texture_regions", "write_textured_mesh", "TextureOptions", "TextureAtlas", "evaluate", "mesh_distances", "mesh_topology", "read_volume", "write_volume", "to_pyopenvdb", "from_pyopenvdb",
    "version", "stage_volume_path",
    "PointCloud", "Mesh", "Volume", "PipelineOptions", "ReadOptions", "WriteOptions",
    "OutlierOptions", "NormalOptions", "KnnOptions", "SplatOptions", "CloseOptions", "MeshOptions",
    "CleanOptions", "HoleFillOptions", "HoleFillResult", "EvalOptions", "ReadResult", "OutlierResult", "NormalResult", "SplatResult",
    "CloseResult", "MeshResult", "CleanResult", "EvalResult", "PipelineResult", "RunResult",
    "TopologyStats", "FScore", "StageTiming", "Error", "IoError", "FormatError",
    "InvalidArgument", "NumericalError",
]

# ---- arrays ----------------------------------------------------------------------------------


def _as_array(a, name, cols):
    """`a` as a C-contiguous float32 array of shape (N, cols) (or (N,) when cols is None):
    returned as is when it already is one, converted once otherwise."""
    expected = f"(N, {cols})" if cols else "(N,)"
    if isinstance(a, _np.ndarray) and a.dtype == _np.float32 and a.flags.c_contiguous \
            and a.dtype.isnative:
        arr = a
    else:
        try:
            arr = _np.asarray(a)
        except Exception as e:  # ragged lists and the like
            raise TypeError(f"{name}: expected an array-like of shape {expected} of real "
                            f"numbers, got {type(a).__name__} ({e})") from None
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{name}: expected real numbers (float32 preferred) of shape "
                            f"{expected}, got dtype {arr.dtype}")
    shape_ok = arr.ndim == 2 and arr.shape[1] == cols if cols else arr.ndim == 1
    if not shape_ok:
        raise ValueError(f"{name}: expected shape {expected}, got {arr.shape}")
    return _np.ascontiguousarray(arr, dtype=_np.float32)  # no copy when it already fits


def _as_points(a, name="points"):
    arr = _as_array(a, name, 3)
    finite = _np.isfinite(arr).all(axis=1)
    if not finite.all():
        bad = _np.flatnonzero(~finite)
        raise ValueError(f"{name}: {bad.size} rows are not finite (first: row {bad[0]}); "
                         f"drop them first, e.g. {name}[np.isfinite({name}).all(axis=1)]")
    return arr


def _cloud(points, normals=None, colors=None, scales=None):
    """A PointCloud from arrays, or the given PointCloud (with attributes added: a new one)."""
    if isinstance(points, PointCloud):
        if normals is None and colors is None and scales is None:
            return points
        c = points
        return PointCloud(
            c.positions,
            normals=_as_array(normals, "normals", 3) if normals is not None else c.normals,
            colors=_as_array(colors, "colors", 3) if colors is not None else c.colors,
            scales=_as_array(scales, "scales", None) if scales is not None else c.scales,
            confidences=c.confidences, origin=c.origin)
    return PointCloud(
        _as_points(points),
        normals=None if normals is None else _as_array(normals, "normals", 3),
        colors=None if colors is None else _as_array(colors, "colors", 3),
        scales=None if scales is None else _as_array(scales, "scales", None))


def _path(p, name="path"):
    try:
        return _os.fspath(p)
    except TypeError:
        raise TypeError(f"{name}: expected a path (str or os.PathLike), got "
                        f"{type(p).__name__}") from None


def _mesh(m, name):
    if isinstance(m, Mesh):
        return m
    if isinstance(m, (str, bytes, _os.PathLike)):
        return read_mesh(m)
    raise TypeError(f"{name}: expected a vdbrecon.Mesh or a mesh file path, got "
                    f"{type(m).__name__}")


# ---- options ---------------------------------------------------------------------------------


def _set_field(struct, field, value, func, name):
    if isinstance(value, _os.PathLike) and isinstance(getattr(type(struct)(), field), str):
        value = _os.fspath(value)  # paths (job_dir, preview_path) as pathlib paths too
    try:
        setattr(struct, field, value)
    except TypeError as e:
        if field in type(struct)._choices:  # the binding's message lists the choices
            raise TypeError(f"{func}(): option '{name}': {e}") from None
        default = getattr(type(struct)(), field)
        kind = "a sequence of 3 numbers or None" if field in ("viewpoint", "up") else \
            type(default).__name__
        raise TypeError(f"{func}(): option '{name}' expects {kind} (default {default!r}), got "
                        f"{type(value).__name__} {value!r}") from None


def _unknown(func, name, valid):
    return TypeError(f"{func}() got an unexpected keyword argument '{name}'; valid options: "
                     + ", ".join(sorted(valid)))


# knn= and knn_eps=: KnnOptions' fields, for the structs that nest one (_fill) and for both
# neighbour stages at once in reconstruct() and run() (_fill_pipeline).
_KNN_FIELDS = {"knn": "backend", "knn_eps": "eps"}
_KNN_ENTRIES = [(k, KnnOptions, f) for k, f in _KNN_FIELDS.items()]


def _fill(cls, kwargs, func):
    """A `cls` options struct with `kwargs` set (its field names; knn= and knn_eps= on the
    neighbour search of the structs that have one)."""
    struct = cls()
    fields = [f for f, _ in cls._fields]
    has_knn = "knn" in getattr(cls, "_stages", ())
    for name, value in kwargs.items():
        if has_knn and name in _KNN_FIELDS:
            _set_field(struct.knn, _KNN_FIELDS[name], value, func, name)
            continue
        if name not in fields:
            raise _unknown(func, name, fields + (list(_KNN_FIELDS) if has_knn else []))
        _set_field(struct, name, value, func, name)
    return struct


# A plain keyword name that several structs have, and the stage it means: the one the CLI flag of
# that name sets (--k sets normals.k; the outlier stage's k is outliers_k).
_PLAIN_NAME_OWNER = {"k": "normals", "max_error": "decimate"}
# Fields taken only as <stage>_<field>: their plain name would not say which stage they switch
# (outliers_enabled).
_QUALIFIED_ONLY = ("enabled",)


def _keyword_names(places, reserved):
    """Keyword name -> (place, field) for the fields of several options structs. `places` maps a
    place -- a stage name, or None for fields taken by their own name only -- to (struct class,
    field names). Every field goes by its own name when that is unambiguous (one struct has it or
    _PLAIN_NAME_OWNER picks one, it is not a parameter name and not in _QUALIFIED_ONLY), and
    always as <stage>_<field>. Read from the bound structs, so new stages and fields appear by
    themselves."""
    where = {}
    for place, (_, fields) in places.items():
        for f in fields:
            where.setdefault(f, []).append((place, f))
    names = {}
    for name, found in where.items():
        if len(found) > 1 and name in _PLAIN_NAME_OWNER:
            found = [p for p in found if p[0] == _PLAIN_NAME_OWNER[name]]
        if len(found) == 1 and name not in reserved and name not in _QUALIFIED_ONLY:
            names[name] = found[0]
    for place, (_, fields) in places.items():
        for f in fields if place is not None else ():
            names.setdefault(f"{place}_{f}", (place, f))
    return names


def _pipeline_places(stages, top_fields):
    """_keyword_names places of PipelineOptions: its stages in pipeline order, then its own
    fields."""
    default = PipelineOptions()
    places = {}
    for stage in stages:
        cls = type(getattr(default, stage))
        places[stage] = (cls, [f for f, _ in cls._fields])
    places[None] = (PipelineOptions, list(top_fields))
    return places


def _fill_keywords(names, kwargs, func, structs):
    """Sets each keyword (a _keyword_names name) on structs[place]; returns `structs`."""
    seen = {}
    for name, value in kwargs.items():
        if name not in names:
            raise _unknown(func, name, names)
        place, field = names[name]
        if (place, field) in seen:
            raise TypeError(f"{func}(): '{name}' and '{seen[place, field]}' set the same option")
        seen[place, field] = name
        _set_field(structs[place], field, value, func, name)
    return structs




def _fill_pipeline(names, kwargs, func):
    o = PipelineOptions()
    kwargs = dict(kwargs)
    knn = {keyword: kwargs.pop(keyword) for keyword in _KNN_FIELDS if keyword in kwargs}
    _fill_keywords(names, kwargs, func, {None: o, **{s: getattr(o, s) for s in o._stages}})
    for keyword, value in knn.items():  # one neighbour search for the outlier and normal stages
        for stage in (o.outliers, o.normals):
            _set_field(stage.knn, _KNN_FIELDS[keyword], value, func, keyword)
    return o


def _options_doc(entries, defaults):
    """Docstring lines for (keyword, struct class, field) entries, grouped by struct, with the
    defaults read from default-constructed structs (or `defaults`, keyword -> value)."""
    lines = []
    group = None
    for keyword, cls, field in entries:
        if cls is not group and len({c for _, c, _ in entries}) > 1:
            group = cls
            lines.append(f"  {cls.__name__}:")
        doc = dict(cls._fields)[field]
        default = defaults.get(keyword, getattr(cls(), field))
        choices = cls._choices.get(field)
        head = f"    {keyword} = {default!r}"
        if choices:
            head += "  (" + " | ".join(repr(c) for c in choices) + ")"
        lines.append(head)
        lines.extend(_textwrap.wrap(doc, 92, initial_indent=" " * 8, subsequent_indent=" " * 8))
    return "\n".join(lines)


def _struct_entries(cls, exclude=()):
    return [(f, cls, f) for f, _ in cls._fields if f not in exclude]


def _keyword_entries(names, places):
    """(keyword, struct class, field) per field of `places`, under its shortest name, in the
    order of `places` and of the fields."""
    primary = {}
    for name, key in names.items():  # the flat name when there is one
        if key not in primary or len(name) < len(primary[key]):
            primary[key] = name
    order = list(places)

    def position(key):
        place, field = key
        return order.index(place), places[place][1].index(field)
    return [(primary[key], places[key[0]][0], key[1]) for key in sorted(primary, key=position)]


def _document(func, summary, entries, params_before, extra_params=(), returns="", defaults=None):
    """Sets func.__doc__ (options with units and defaults) and func.__signature__. `defaults`
    (keyword -> value) overrides the struct's default where the function sets its own."""
    defaults = defaults or {}
    params = list(params_before)
    for keyword, cls, field in entries:
        params.append(_inspect.Parameter(keyword, _inspect.Parameter.KEYWORD_ONLY,
                                         default=defaults.get(keyword, getattr(cls(), field))))
    params.extend(extra_params)
    func.__signature__ = _inspect.Signature(params)
    func.__doc__ = summary.rstrip() + "\n\nOptions (keyword only; defaults read from the C++ " \
        "options structs):\n" + _options_doc(entries, defaults) + \
        ("\n\n" + returns if returns else "")
    return func


_P = _inspect.Parameter


def _pos(name, default=_P.empty):
    return _P(name, _P.POSITIONAL_OR_KEYWORD, default=default)


def _kw(name, default):
    return _P(name, _P.KEYWORD_ONLY, default=default)


# ---- files -----------------------------------------------------------------------------------


def read_points(path, **options):
    return _v.read_points(_path(path), _fill(ReadOptions, options, "read_points"))


_document(read_points, """Reads a point cloud: PLY (ascii/binary), XYZ/PTS text, OBJ (v/vn),
PCD, LAS.

Returns a ReadResult: .cloud (PointCloud with positions, normals, colors, scales,
confidences as numpy views), .format, .rows, .dropped_nonfinite, .invalid_normals; for LAS
also .classification, .intensity, .return_number, .number_of_returns (numpy, one per point).
Raises IoError / FormatError (OSError) naming the file.""",
          _struct_entries(ReadOptions), [_pos("path")])


def read_mesh(path):
    """Reads a triangle mesh (.ply with faces, .obj); returns a Mesh."""
    return _v.read_mesh(_path(path))


def write_mesh(path, mesh, **options):
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh: expected a vdbrecon.Mesh, got {type(mesh).__name__} "
                        "(build one with vdbrecon.Mesh(vertices, faces))")
    _v.write_mesh(_path(path), mesh, _fill(WriteOptions, options, "write_mesh"))


_document(write_mesh, """Writes a Mesh as .ply or .obj (by extension), atomically.""",
          _struct_entries(WriteOptions), [_pos("path"), _pos("mesh")])


def write_points(path, cloud, **options):
    _v.write_points(_path(path), _cloud(cloud), _fill(WriteOptions, options, "write_points"))


_document(write_points, """Writes a point cloud (PointCloud or (N, 3) array) as .ply or .xyz.""",
          _struct_entries(WriteOptions), [_pos("path"), _pos("cloud")])


def read_volume(path):
    """Reads a .vdb file with a level-set 'sdf' grid (as written by write_volume or the CLI)."""
    return _v.read_volume(_path(path))


def write_volume(path, volume):
    """Writes a Volume's grids (sdf, weight, nearest, density, color, fill) to a .vdb file."""
    _v.write_volume(_path(path), _volume(volume))


# ---- pyopenvdb -------------------------------------------------------------------------------


def _pyopenvdb():
    try:
        import pyopenvdb
    except ImportError as e:
        raise ImportError("pyopenvdb is not importable (Debian: apt-get install python3-openvdb, "
                          f"and use /usr/bin/python3): {e}") from None
    return pyopenvdb


def _is_pyopenvdb_grid(obj):
    return type(obj).__module__ == "pyopenvdb"


def to_pyopenvdb(volume):
    """The volume's grids as pyopenvdb objects: {'sdf': FloatGrid, 'weight': FloatGrid,
    'nearest': Vec3SGrid, 'density': FloatGrid, 'color': Vec3SGrid and 'fill': FloatGrid (when
    present)}.

    Copied through a temporary .vdb file (Debian's pyopenvdb is Boost.Python and shares no
    objects with this module); needs pyopenvdb."""
    pyopenvdb = _pyopenvdb()
    tmp = _tempfile.mkdtemp(prefix="vdbrecon_")
    try:
        path = _os.path.join(tmp, "volume.vdb")
        write_volume(path, volume)
        grids, _ = pyopenvdb.readAll(path)
        return {g.name: g for g in grids}
    finally:
        _shutil.rmtree(tmp, ignore_errors=True)


def from_pyopenvdb(grids):
    """A Volume from pyopenvdb grids: a level-set FloatGrid (used as 'sdf' whatever its name), or
    a list/dict of grids among which one is named 'sdf' ('weight', 'nearest', 'color', 'fill' are
    used when present). Copied through a temporary .vdb file; needs pyopenvdb."""
    pyopenvdb = _pyopenvdb()
    if isinstance(grids, dict):
        grids = list(grids.values())
    elif _is_pyopenvdb_grid(grids):
        if grids.name != "sdf":
            grids = grids.deepCopy()
            grids.name = "sdf"
        grids = [grids]
    grids = list(grids)
    if not all(_is_pyopenvdb_grid(g) for g in grids):
        raise TypeError("from_pyopenvdb: expected pyopenvdb grids")
    if "sdf" not in [g.name for g in grids]:
        raise ValueError("from_pyopenvdb: no grid named 'sdf' among "
                         f"{[g.name for g in grids]}")
    tmp = _tempfile.mkdtemp(prefix="vdbrecon_")
    try:
        path = _os.path.join(tmp, "volume.vdb")
        pyopenvdb.write(path, grids=grids)
        return read_volume(path)
    finally:
        _shutil.rmtree(tmp, ignore_errors=True)


def _volume(v):
    if isinstance(v, Volume):
        return v
    if isinstance(v, (str, bytes, _os.PathLike)):
        return read_volume(v)
    if _is_pyopenvdb_grid(v) or (isinstance(v, (list, tuple, dict)) and v and all(
            _is_pyopenvdb_grid(g) for g in (v.values() if isinstance(v, dict) else v))):
        return from_pyopenvdb(v)
    raise TypeError("volume: expected a vdbrecon.Volume, a .vdb path or pyopenvdb grids, got "
                    f"{type(v).__name__}")


# ---- stages ----------------------------------------------------------------------------------


def remove_outliers(points, normals=None, colors=None, **options):
    options.setdefault("enabled", True)
    return _v.remove_outliers(_cloud(points, normals, colors),
                              _fill(OutlierOptions, options, "remove_outliers"))


_document(remove_outliers, """Removes stray points, as reconstruct() does first.

A point goes when its mean distance d_i to its k nearest neighbours exceeds statistical_ratio x
its neighbours' mean d_j (statistical rule), or when its neighbourhood is not planar
(lambda_0 / lambda_1 > planarity_ratio) and sparse (d_i > planarity_spacing x the cloud's
median d) (planarity rule).

points: PointCloud or (N, 3) array, world units; normals, colors: optional (N, 3) arrays that
are filtered along (as are a PointCloud's scales and confidences).
enabled is True here whatever OutlierOptions' default: calling this function runs the removal
(enabled=False returns every point). Nothing is removed with fewer than k + 1 points.
Returns an OutlierResult: .cloud (PointCloud of the kept points, input order), .removed (N,)
bool, True for each removed input point, .statistical and .planarity (counts per rule).""",
          _struct_entries(OutlierOptions) + _KNN_ENTRIES,
          [_pos("points"), _pos("normals", None), _pos("colors", None)],
          defaults={"enabled": True})


def estimate_normals(points, normals=None, **options):
    return _v.estimate_normals(_cloud(points, normals),
                               _fill(NormalOptions, options, "estimate_normals"))


_document(estimate_normals, """Estimates normals (PCA over the k nearest neighbours, oriented
towards `viewpoint` or by minimum-spanning-tree propagation, Hoppe 1992) and per-point scales.

points: PointCloud or (N, 3) array, world units; normals: optional (N, 3) array (kept, or
repaired where zero/NaN, per `mode`).
Returns a NormalResult: .normals (N, 3), .scales (N,) or None, and counts.""",
          _struct_entries(NormalOptions) + _KNN_ENTRIES, [_pos("points"), _pos("normals", None)])


def splat(points, normals=None, colors=None, scales=None, *, voxel=None, **options):
    if voxel is not None:
        if "voxel_size" in options:
            raise TypeError("splat(): give voxel or voxel_size, not both")
        options["voxel_size"] = voxel
    return _v.splat(_cloud(points, normals, colors, scales), _fill(SplatOptions, options, "splat"))


_document(splat, """Splats oriented points into a Volume (Gaussian-weighted signed distance,
FSSR, Fuhrmann and Goesele 2014).

points: PointCloud or (N, 3) array; normals (N, 3) required (here or in the cloud); colors
(N, 3) linear 0..1; scales (N,) footprints in world units (see estimate_normals).
voxel: voxel edge in world units (same as voxel_size; required here, > 0).
Returns a SplatResult: .volume and statistics.""",
          _struct_entries(SplatOptions),
          [_pos("points"), _pos("normals", None), _pos("colors", None), _pos("scales", None),
           _kw("voxel", None)])


# close(): CloseOptions fields, and MeshOptions fields (the trims that decide which voxels the
# closing starts from), each by its own name or as close_<field> / mesh_<field>.
_CLOSE_PLACES = {s: (c, [f for f, _ in c._fields]) for s, c in
                 (("close", CloseOptions), ("mesh", MeshOptions))}
_CLOSE_NAMES = _keyword_names(_CLOSE_PLACES, ("volume",))
_CLOSE_RADII = ("hole_radius", "solid_radius")


def close(volume, **options):
    o = _fill_keywords(_CLOSE_NAMES, options, "close",
                       {"close": CloseOptions(), "mesh": MeshOptions()})
    if not any(_CLOSE_NAMES[n][1] in _CLOSE_RADII for n in options):
        raise TypeError("close() needs hole_radius=R and/or solid_radius=R (voxels); with "
                        "neither it would return the volume unchanged")
    return _v.close_volume(_volume(volume), o["close"], o["mesh"])


_document(close, """Closes the volume before meshing (dilate > fill > erode), as
reconstruct(hole_radius=..., solid_radius=...) does between splat and mesh.

Hole closing (hole_radius R) closes the supported voxels -- the valid voxels that the mesher's
trims support (min_surface_weight, max_gap), extruded R voxels along the surface normal -- with
a (2R+1)^3 cube: holes at least 2R voxels across are covered, open borders stay; new voxels get
the field extended from their neighbours, and the mesher never trims what the closing covered. Solid closing (solid_radius R) offsets a watertight surface out by R voxels and
back: concavities narrower than about 2R disappear. With both, holes are closed first.
At least one radius must be given (TypeError otherwise; explicit zeros return the input).

volume: Volume, .vdb path, or pyopenvdb grid(s), e.g. splat(...).volume.
Options: the CloseOptions fields, and the MeshOptions fields by their own names (give the same
ones to extract_mesh() on the result); each also as close_<field> / mesh_<field>.
Returns a CloseResult: .volume (with a 'fill' grid: the voxels the closing vouches for, where
extract_mesh keeps faces whatever their weight or gap) and voxel counts.
Raises NumericalError when solid closing finds no watertight surface.""",
          _keyword_entries(_CLOSE_NAMES, _CLOSE_PLACES), [_pos("volume")])


def extract_mesh(volume, **options):
    return _v.extract_mesh(_volume(volume), _fill(MeshOptions, options, "extract_mesh"))


_document(extract_mesh, """Extracts the iso-surface of the volume's sdf grid; faces only in valid
cells, trimmed where the data ends.

volume: Volume, .vdb path, or pyopenvdb grid(s) (see from_pyopenvdb).
Returns a MeshResult: .mesh, .dropped_faces, .trimmed_faces.""",
          _struct_entries(MeshOptions), [_pos("volume")])


def clean_mesh(mesh, support=None, **options):
    return _v.clean_mesh(_mesh(mesh, "mesh"), _fill(CleanOptions, options, "clean_mesh"), support)


_document(clean_mesh, """Removes the edge-connected components too few samples built (and, with
min_component_ratio, small ones) and optionally smooths (Taubin lambda|mu, boundary vertices
fixed).

mesh: Mesh or mesh path. support: optional (V,) per-vertex summed weight (MeshResult.support);
without it every face counts as fully supported.
Returns a CleanResult: .mesh, .components_before, .removed_components, .removed_faces.""",
          _struct_entries(CleanOptions), [_pos("mesh")])


def fill_holes(mesh, **options):
    return _v.fill_holes(_mesh(mesh, "mesh"), _fill(HoleFillOptions, options, "fill_holes"))


_document(fill_holes, """Fills the mesh's boundary loops (Liepa 2003): a minimum-dihedral, then
minimum-area triangulation of each loop, refined to the density around it and faired (the new
vertices solve the bi-Laplacian with the mesh fixed), as reconstruct(fill_holes=N) and
reconstruct(watertight=True) do after the clean stage.

mesh: Mesh or mesh path.
Returns a HoleFillResult: .mesh, .loops, .filled, .added_faces, .added_vertices,
.largest_filled, .largest_open.""",
          _struct_entries(HoleFillOptions), [_pos("mesh")])


def decimate(mesh, **options):
    return _v.decimate(_mesh(mesh, "mesh"), _fill(DecimateOptions, options, "decimate"))


_document(decimate, """Decimates a mesh by quadric error metric edge collapses (Garland and
Heckbert 1997), as reconstruct(ratio=..., max_error=...) does last: no collapse flips a face,
makes the mesh non-manifold or changes its topology; open borders stay put; colours follow.

mesh: Mesh or mesh path.
Returns a DecimateResult: .mesh, .faces_before, .faces_after, .collapses, .max_error.""",
          _struct_entries(DecimateOptions), [_pos("mesh")])


def planar_regions(mesh, voxel, **options):
    return _v.planar_regions(_mesh(mesh, "mesh"), _fill(PlaneOptions, options, "planar_regions"),
                             voxel)


_document(planar_regions, """Finds the planar regions of a mesh by region growing, moves the
vertices onto their planes (onto the line of two planes at an edge, the point of three at a
corner) and re-triangulates the regions with few faces, as reconstruct(planes_enabled=True)
does after the hole filling. Lengths are in voxels of `voxel` (world units).

mesh: Mesh or mesh path.
Returns a PlaneResult: .mesh (with .regions per face), .planes, .faces_before, .faces_after,
.planar_faces, .edge_vertices, .corner_vertices.""",
          _struct_entries(PlaneOptions), [_pos("mesh"), _pos("voxel")])


def texture_regions(mesh, planes, points, voxel, colors=None, **options):
    return _v.texture_regions(_mesh(mesh, "mesh"), list(planes), _cloud(points, colors=colors),
                              _fill(TextureOptions, options, "texture_regions"), voxel)


_document(texture_regions, """Textures the planar regions of a mesh (its .regions, as
planar_regions() or reconstruct(planes_enabled=True) leave them; `planes` that result's .planes)
from the colours of the points (a PointCloud with colors, or (N, 3) positions with `colors`),
as reconstruct(texture_enabled=True) does last. Lengths are in voxels of `voxel` (world units).

Returns a TextureAtlas: .image ((H, W, 3) uint8), .uv ((F, 3, 2) per face corner, NaN outside
the regions), .texel, .regions, .points, .texels, .texels_seen.""",
          _struct_entries(TextureOptions), [_pos("mesh"), _pos("planes"), _pos("points"),
                                            _pos("voxel"), _pos("colors", None)])


def write_textured_mesh(path, mesh, atlas):
    """Writes a Mesh with a TextureAtlas as an OBJ (`path`, .obj) with its material file
    (<stem>.mtl) and the atlas picture (<stem>.texture.png), atomically."""
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh: expected a vdbrecon.Mesh, got {type(mesh).__name__}")
    _v.write_textured_mesh(_path(path), mesh, atlas)


def evaluate(recon, reference, **options):
    return _v.evaluate(_mesh(recon, "recon"), _mesh(reference, "reference"),
                       _fill(EvalOptions, options, "evaluate"))


_document(evaluate, """Compares a reconstruction with a reference mesh (Mesh objects or paths):
accuracy, completeness, Chamfer-L1, Hausdorff (world units), precision/recall/F per tau,
normal consistency and topology. EvalResult.to_json() is what `vdbrecon eval` prints.""",
          _struct_entries(EvalOptions), [_pos("recon"), _pos("reference")])


def mesh_distances(mesh, points):
    """Distance (world units) from each of `points` (N x 3) to the closest point of `mesh` (a
    Mesh or mesh path), and the index of that closest face: (float64 array, int32 array)."""
    return _v.mesh_distances(_mesh(mesh, "mesh"), _cloud(points))


def mesh_topology(mesh):
    """TopologyStats of a Mesh (or mesh path): components, boundary and non-manifold edges,
    Euler characteristic, area, signed volume."""
    return _v.mesh_topology(_mesh(mesh, "mesh"))


# ---- the whole pipeline ----------------------------------------------------------------------

_RECONSTRUCT_PARAMS = ("points", "normals", "colors", "voxel", "return_result")
# Stages and fields of PipelineOptions that only matter when files are read or written.
_FILE_ONLY_STAGES = ("read", "write")
_FILE_ONLY_FIELDS = ("write_vdb",)
_RECONSTRUCT_PLACES = _pipeline_places(
    [s for s in PipelineOptions._stages if s not in _FILE_ONLY_STAGES],
    [f for f, _ in PipelineOptions._fields if f not in _FILE_ONLY_FIELDS])
_RECONSTRUCT_NAMES = _keyword_names(_RECONSTRUCT_PLACES, _RECONSTRUCT_PARAMS)
_RUN_PARAMS = ("input", "output", "voxel")
_RUN_PLACES = _pipeline_places(PipelineOptions._stages, [f for f, _ in PipelineOptions._fields])
_RUN_NAMES = _keyword_names(_RUN_PLACES, _RUN_PARAMS)


def _voxel_option(voxel, options, func):
    if voxel is not None:
        if any(n in options for n in ("voxel_size", "splat_voxel_size")):
            raise TypeError(f"{func}(): give voxel or voxel_size, not both")
        options["voxel_size"] = voxel


def reconstruct(points, normals=None, colors=None, *, voxel=None, return_result=False,
                **options):
    _voxel_option(voxel, options, "reconstruct")
    o = _fill_pipeline(_RECONSTRUCT_NAMES, options, "reconstruct")
    cloud = _cloud(points, normals, colors)
    result = _v.reconstruct(cloud, o)
    return result if return_result else result.mesh


_document(reconstruct, """Reconstructs a triangle mesh from a point cloud: outlier removal >
normals and scales > Gaussian splat into sparse OpenVDB grids > closing (off by default) > mesh
extraction > cleanup.

points: (N, 3) array (float32 used as is, other real dtypes converted once) or PointCloud,
world units. normals: (N, 3) outward normals, optional (estimated when missing, see `mode`).
colors: (N, 3) linear 0..1 RGB, optional (splatted into the volume's color grid).
voxel: voxel edge in world units; None chooses auto_voxel_factor x the median point spacing.
Every option below is a field of PipelineOptions or of one of its stage structs, given by its
own name, or as <stage>_<field> (always accepted; required for mesh_normals, whose plain name
is the `normals` argument, for outliers_k, as plain `k` is the normals' k like the CLI's --k,
and for outliers_enabled).
return_result: return the PipelineResult (mesh, volume, closed_volume, statistics, timings)
instead of the Mesh.

Returns a Mesh: .vertices (V, 3) float32, .faces (F, 3) int32 (counter-clockwise seen from
outside), .normals (V, 3) or None, .colors or None, .origin.
Raises InvalidArgument (ValueError) for options out of range, NumericalError when nothing can
be reconstructed, TypeError for unknown options.""",
          _keyword_entries(_RECONSTRUCT_NAMES, _RECONSTRUCT_PLACES) + _KNN_ENTRIES,
          [_pos("points"), _pos("normals", None), _pos("colors", None), _kw("voxel", None),
           _kw("return_result", False)])


def run(input, output=None, *, voxel=None, **options):
    _voxel_option(voxel, options, "run")
    o = _fill_pipeline(_RUN_NAMES, options, "run")
    return _v.run(_path(input, "input"), "" if output is None else _path(output, "output"), o)


_document(run, """Reads `input`, reconstructs and writes `output` (.ply or .obj; None:
<input stem>.recon.ply), <output stem>.splat.vdb and, when closing, <output stem>.closed.vdb:
exactly what the CLI does, `vdbrecon INPUT -o OUTPUT ...`, with the same options (read_*,
write_* included; keywords as in reconstruct()).

Returns a RunResult: .result (PipelineResult), .read (ReadResult counts), .mesh_path,
.vdb_path, .closed_vdb_path.""",
          _keyword_entries(_RUN_NAMES, _RUN_PLACES) + _KNN_ENTRIES, [_pos("input"), _pos("output", None),
                                                      _kw("voxel", None)])


# ---- range-image fusion ----------------------------------------------------------------------

_DEPTH_FIELDS = [f for f, _ in DepthOptions._fields]


def _intrinsics(K, name):
    """fx, fy, cx, cy from a (3, 3) matrix or 4 numbers."""
    k = _np.asarray(K, dtype=_np.float64)
    if k.shape == (3, 3):
        return k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    if k.shape == (4,):
        return tuple(k)
    raise ValueError(f"{name}: expected a (3, 3) matrix or (fx, fy, cx, cy)")


class Fusion:
    """Fuses posed depth images (and oriented clouds) into one volume, one frame at a time
    (FSSR-style samples: normals from the depth neighbours, scale from the pixel footprint,
    confidence from the viewing angle), then meshes it like reconstruct().

    voxel: voxel edge, world units (required).
    origin: world position of the local float frame (pick one near the scene).
    depth_scale: integer depth arrays are divided by it (units per metre, as Open3D's).
    Options: every reconstruct() option by the same name (method, hole_radius, ...), and the
    DepthOptions fields (kind or depth_kind, min_depth, max_depth, max_jump, min_view_cos,
    reference_depth).
    """

    def __init__(self, voxel, *, origin=(0.0, 0.0, 0.0), depth_scale=1000.0, **options):
        depth = {}
        for name in list(options):
            field = name[len("depth_"):] if name.startswith("depth_") else name
            # `aggregate` is also the splat's (points), which a fusion does not use: the depth
            # option's here, as --aggregate in `vdbrecon fuse`.
            if field in _DEPTH_FIELDS and (name not in _RECONSTRUCT_NAMES or name == "aggregate"):
                depth[field] = options.pop(name)
        if "voxel_size" in options or "splat_voxel_size" in options:
            raise TypeError("Fusion(): give voxel, not voxel_size")
        options["voxel_size"] = voxel
        o = _fill_pipeline(_RECONSTRUCT_NAMES, options, "Fusion")
        if not depth_scale > 0:
            raise ValueError("Fusion(): depth_scale must be > 0 (units per metre)")
        self._depth_scale = float(depth_scale)
        self._f = _v._Fusion(o, _fill(DepthOptions, depth, "Fusion"), tuple(float(x) for x in origin))

    def integrate(self, depth, K, pose, *, convention="opencv", color=None, color_K=None):
        """Adds one depth image.

        depth: (H, W) array; float: world units, integer: units of 1/depth_scale; 0, NaN and
        inf are no measurement.
        K: (3, 3) intrinsic matrix, or (fx, fy, cx, cy), pixels (pixel centres at integers).
        pose: (4, 4) camera-to-world transform; convention 'opencv' (x right, y down, looking
        down +z; TUM, Open3D after inverting its extrinsic) or 'opengl' (y up, looking down -z;
        Blender, NeRF transforms.json).
        color: the frame's colour image seen from the same pose, (H', W', 3); uint8 (0..255)
        or float (0..1). Each sample takes the colour its camera saw, weighted like its
        distance: the mesh gets vertex colours.
        color_K: the colour camera's intrinsics when they are not K's; by default K, scaled to
        the colour image's size.
        Returns the number of samples the frame gave."""
        d = _np.asarray(depth)
        if d.dtype.kind in "iu":
            d = d.astype(_np.float32) / _np.float32(self._depth_scale)
        fx, fy, cx, cy = _intrinsics(K, "K")
        p = _np.array(pose, dtype=_np.float64)
        if p.shape != (4, 4):
            raise ValueError("pose: expected a (4, 4) camera-to-world matrix")
        if convention == "opengl":
            p[:3, 1:3] *= -1.0
        elif convention != "opencv":
            raise ValueError("convention: 'opencv' or 'opengl'")
        if color is None:
            if color_K is not None:
                raise ValueError("color_K: given without color")
            return self._f.integrate_depth(d, float(fx), float(fy), float(cx), float(cy), p)
        c = _np.asarray(color)
        if c.ndim != 3 or c.shape[2] != 3:
            raise ValueError("color: expected an (H, W, 3) array")
        c = c.astype(_np.float32) / _np.float32(255.0) if c.dtype == _np.uint8 else c.astype(_np.float32)
        if d.ndim != 2:
            raise ValueError("depth: expected an (H, W) array")
        if color_K is None:  # K scaled to the colour image (pixel centres at integers)
            sx, sy = c.shape[1] / d.shape[1], c.shape[0] / d.shape[0]
            cfx, cfy, ccx, ccy = fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5
        else:
            cfx, cfy, ccx, ccy = _intrinsics(color_K, "color_K")
        return self._f.integrate_color(d, float(fx), float(fy), float(cx), float(cy), p, c,
                                       float(cfx), float(cfy), float(ccx), float(ccy))

    def integrate_scan(self, points, sensor, *, colors=None):
        """Adds one LiDAR scan: its points (N, 3) in world coordinates (or a PointCloud),
        measured from the sensor at `sensor` (world, 3 values). With the splat rule the
        points become samples with normals from the scan's own neighbours, toward the sensor;
        with rule='tsdf' the voxels each ray crosses are updated, and the free space in front
        of each hit carved. colors: (N, 3) per point, optional.
        Returns the number of samples (or hits) used."""
        s = _np.asarray(sensor, dtype=_np.float64).reshape(-1)
        if s.shape != (3,) or not _np.all(_np.isfinite(s)):
            raise ValueError("sensor: expected 3 finite numbers")
        return self._f.integrate_scan(_cloud(points, None, colors), tuple(float(x) for x in s))

    def integrate_points(self, points, normals=None):
        """Adds an oriented cloud (e.g. one scan with normals toward its sensor)."""
        return self._f.integrate_cloud(_cloud(points, normals))

    def volume(self):
        """The fused Volume so far."""
        return self._f.volume()

    def mesh(self, return_result=False):
        """The mesh of the fused volume (close > mesh > clean > fill, by the options); with
        return_result the PipelineResult."""
        r = self._f.reconstruct()
        return r if return_result else r.mesh

    @property
    def frames(self):
        return self._f.frames

    @property
    def samples(self):
        return self._f.samples
