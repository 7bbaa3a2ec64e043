"""Interop check with the real clients, run before resolving a change to the .vdb files:

  1. the CLI reconstructs a coloured sphere, writing ball.splat.vdb, the same sphere with its top
     cap cut away with `--close 4`, writing ball_closed.closed.vdb (the splat grids plus `fill`,
     which must be non-empty: closing patched the hole), and data/bunny_sample.ply;
  2. vdb_print -l lists every grid of both sphere files with its class;
  3. pyopenvdb reads every grid of both with the right name, class, active voxels and values;
  4. Blender (headless) imports each sphere file, renders the `density` grid with Cycles to a PNG
     and meshes the `sdf` grid with a VOLUME_TO_MESH modifier: that mesh must have as many
     triangles as the mesh vdbrecon wrote in the same run plus the ones vdbrecon's mesher
     dropped (cells with an invalid corner, low weight: its log counts them; the modifier meshes
     every active voxel), and the same bounding box up to Blender's half-voxel shift (for the
     capped sphere, whose dropped faces lie outside: a box holding vdbrecon's).

    PYTHONPATH=build-py/python /usr/bin/python3 python/tools/interop_check.py \
        --cli build-py/vdbrecon --out out/interop

Exit status 0 when every check passed. Needs python3-openvdb, libopenvdb-tools and blender.
"""
import argparse
import json
import math
import pathlib
import re
import shutil
import subprocess
import sys
import time

import numpy as np

import vdbrecon

HERE = pathlib.Path(__file__).resolve().parent
SOURCE_DIR = HERE.parents[1]
VOXEL = 0.02
# Grid name -> (pyopenvdb class, grid class) in a coloured <out>.splat.vdb and <out>.closed.vdb.
SPLAT_GRIDS = {"sdf": ("FloatGrid", "level set"), "weight": ("FloatGrid", "unknown"),
               "nearest": ("Vec3SGrid", "unknown"), "density": ("FloatGrid", "fog volume"),
               "color": ("Vec3SGrid", "unknown")}
CLOSED_GRIDS = {**SPLAT_GRIDS, "fill": ("FloatGrid", "unknown")}
# The sphere runs: output stem, input points, CLI options, volume file checked, its grids.
SPHERE_RUNS = [("ball", "ball_points.ply", [], "ball.splat.vdb", SPLAT_GRIDS),
               ("ball_closed", "capped_points.ply", ["--close", "4"], "ball_closed.closed.vdb",
                CLOSED_GRIDS)]
CAP_Y = 0.495  # the capped sphere has no points above this height: a hole 0.14 (7 voxels) wide
failures = []


def check(ok, what):
    print(("  ok    " if ok else "  FAIL  ") + what)
    if not ok:
        failures.append(what)


def sphere(n, radius):
    i = np.arange(n, dtype=np.float64)
    y = 1.0 - 2.0 * (i + 0.5) / n
    r = np.sqrt(1.0 - y * y)
    t = math.pi * (3.0 - math.sqrt(5.0)) * i
    normals = np.stack([r * np.cos(t), y, r * np.sin(t)], axis=1)
    return (radius * normals).astype(np.float32), normals.astype(np.float32)


def vdb_print(path, grids):
    """`vdb_print -l path` lists exactly `grids`, one level set and one fog volume."""
    out = subprocess.run(["vdb_print", "-l", str(path)], capture_output=True, text=True,
                         check=True).stdout
    print("\n".join(l for l in out.splitlines()
                    if l.startswith(("Name:", "  Type:", "  Number of active voxels", "  class:",
                                     "  file_compression", "creator"))))
    names = [l[len("Name: "):] for l in out.splitlines() if l.startswith("Name: ")]
    check(sorted(names) == sorted(grids), f"vdb_print lists {names}")
    check(out.count("class: level set") == 1, "vdb_print: sdf is a level set")
    check(out.count("class: fog volume") == 1, "vdb_print: density is a fog volume")


def pyopenvdb_check(path, grids):
    """pyopenvdb reads exactly `grids` from `path`, each with its class and the active voxels
    and values vdbrecon reads; a `fill` grid must have active voxels (closing filled the hole)."""
    import pyopenvdb
    read, meta = pyopenvdb.readAll(str(path))
    if "fill" in grids:
        fill = [g for g in read if g.name == "fill"]
        count = fill[0].activeVoxelCount() if fill else 0
        check(count > 0, f"pyopenvdb: `fill` marks {count} voxels (the closed set)")
    ours = vdbrecon.read_volume(path)
    check(sorted(g.name for g in read) == sorted(grids),
          f"pyopenvdb grid names {[g.name for g in read]}")
    for g in read:
        cls, grid_class = grids.get(g.name, (None, None))
        coords, values = ours.to_arrays(g.name)
        acc = g.getConstAccessor()
        probed = [acc.probeValue(tuple(int(x) for x in c)) for c in coords]
        got = np.array([value for value, _ in probed])
        # As many active voxels, all of ours active: the same active coordinates.
        check(type(g).__name__ == cls and g.gridClass == grid_class and
              g.activeVoxelCount() == len(coords) and all(on for _, on in probed) and
              np.array_equal(got, values),
              f"pyopenvdb {g.name}: {type(g).__name__}, '{g.gridClass}', "
              f"{g.activeVoxelCount()} active voxels, same coordinates, every value equal")
    print(f"  file metadata: creator={meta.get('creator')!r}")


def blender(path, png, samples):
    start = time.time()
    r = subprocess.run(["blender", "-b", "--factory-startup", "--python",
                        str(HERE / "blender_check.py"), "--", str(path), str(png), str(samples)],
                       capture_output=True, text=True)
    line = [l for l in r.stdout.splitlines() if l.startswith("BLENDER_CHECK ")]
    check(r.returncode == 0 and bool(line), f"blender ran ({time.time() - start:.1f} s)")
    if not line:
        print(r.stdout[-3000:], r.stderr[-3000:])
        return None
    info = json.loads(line[0][len("BLENDER_CHECK "):])
    print(f"  blender grids: {info['grids']}")
    check(png.exists() and png.stat().st_size > 1000,
          f"Cycles rendered {png} in {info['render_seconds']} s")
    return info


def blender_sphere(path, png, samples, grids, mesh, dropped):
    """Blender imports every grid of a sphere's volume `path` and renders it to `png`; its
    VOLUME_TO_MESH mesh of `sdf` has the triangle count of vdbrecon's `mesh` plus the `dropped`
    triangles vdbrecon's mesher left out, and when none were, the same bounding box."""
    info = blender(path, png, samples)
    if not info:
        return
    names = {g["name"]: g for g in info["grids"]}
    check(set(names) == set(grids), f"blender sees grids {sorted(names)}")
    check(names.get("density", {}).get("data_type") == "FLOAT", "density is FLOAT")
    b = info["mesh"]
    check(b["triangles"] == len(mesh.faces) + dropped,
          f"VOLUME_TO_MESH: {b['polygons']} polygons = {b['triangles']} triangles, "
          f"vdbrecon: {len(mesh.faces)} triangles + {dropped} dropped")
    half = 0.5 * VOXEL  # Blender's cell-centred voxels shift its mesh by +voxel/2
    lo = np.array(b["bbox_min"]) - half
    hi = np.array(b["bbox_max"]) - half
    vlo, vhi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    if dropped:  # Blender's mesh has vdbrecon's and the dropped faces: its box holds vdbrecon's
        check(bool((lo <= vlo + 1e-4).all() and (hi >= vhi - 1e-4).all()),
              f"blender's box {lo.round(4)}..{hi.round(4)} holds vdbrecon's {vlo.round(4)}.."
              f"{vhi.round(4)}")
        return
    err = max(np.abs(lo - vlo).max(), np.abs(hi - vhi).max())
    check(err < 1e-4, f"bounding boxes agree within {err:.2e} (blender {lo.round(4)}.."
          f"{hi.round(4)}, vdbrecon {vlo.round(4)}..{vhi.round(4)})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cli", required=True)
    ap.add_argument("--out", default="out/interop")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--no-blender", action="store_true")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # A coloured sphere, radius 0.5, and the same with its top cap cut away (closed by --close).
    points, normals = sphere(40000, 0.5)
    colors = (0.5 + 0.5 * normals).astype(np.float32)
    vdbrecon.write_points(out / "ball_points.ply", vdbrecon.PointCloud(points, normals, colors))
    keep = points[:, 1] < CAP_Y
    vdbrecon.write_points(out / "capped_points.ply",
                          vdbrecon.PointCloud(points[keep], normals[keep], colors[keep]))
    meshes, dropped = {}, {}
    for stem, src, options, vdb, _ in SPHERE_RUNS:
        log = subprocess.run([args.cli, out / src, "-o", out / f"{stem}.ply", "--voxel",
                              str(VOXEL), *options], check=True, capture_output=True,
                             text=True)
        counts = re.search(r"\((\d+) dropped outside valid cells, (\d+) trimmed as unsupported\)",
                           log.stdout + log.stderr)
        check(counts is not None, f"{stem}: the CLI's log counts the faces its mesher dropped")
        dropped[stem] = int(counts[1]) + int(counts[2]) if counts else 0
        meshes[stem] = vdbrecon.read_mesh(out / f"{stem}.ply")
        print(f"vdbrecon {src} {' '.join(options) or '(no closing)'}: {out / vdb}, mesh "
              f"{len(meshes[stem].vertices)} vertices, {len(meshes[stem].faces)} triangles")
        top = meshes[stem].vertices[:, 1].max()
        check(abs(top - 0.5) < 0.5 * VOXEL, f"{stem}: mesh reaches the pole (top y = {top:.4f})")

    for _, _, _, vdb, grids in SPHERE_RUNS:
        print(f"\n== vdb_print -l {vdb}")
        vdb_print(out / vdb, grids)
        print(f"== pyopenvdb {vdb}")
        pyopenvdb_check(out / vdb, grids)
    if args.no_blender or shutil.which("blender") is None:
        print("== blender: skipped")
    else:
        for stem, _, _, vdb, grids in SPHERE_RUNS:
            print(f"== blender {vdb}")
            blender_sphere(out / vdb, (out / f"{stem}_density.png").resolve(), args.samples,
                           grids, meshes[stem], dropped[stem])

        # The bunny sample, for a recognisable picture (open scan: vdbrecon trims its mesh
        # where the data ends, Blender's modifier does not, so only the render is checked).
        print("== blender, data/bunny_sample.ply")
        subprocess.run([args.cli, SOURCE_DIR / "data" / "bunny_sample.ply", "-o",
                        out / "bunny.ply", "-q"], check=True)
        info = blender(out / "bunny.splat.vdb", (out / "bunny_density.png").resolve(),
                       args.samples)
        if info:
            bm = vdbrecon.read_mesh(out / "bunny.ply")
            print(f"  bunny: VOLUME_TO_MESH {info['mesh']['triangles']} triangles, vdbrecon "
                  f"{len(bm.faces)} (trimmed where the scan ends)")

    print("\ninterop: " + ("all checks passed" if not failures else f"{len(failures)} FAILED"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
