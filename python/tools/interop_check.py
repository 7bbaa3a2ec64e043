"""Interop check with the real clients, run before resolving a change to the .vdb files:

  1. the CLI reconstructs a coloured sphere (and data/bunny_sample.ply) and writes <out>.splat.vdb;
  2. vdb_print -l lists every grid with its class;
  3. pyopenvdb reads every grid with the right name, class and values;
  4. Blender (headless) imports the file, renders the `density` grid with Cycles to a PNG and
     meshes the `sdf` grid with a VOLUME_TO_MESH modifier: that mesh must have as many
     triangles as vdbrecon's own mesh (the sphere is closed, so nothing is trimmed) and the same
     bounding box up to Blender's half-voxel shift.

    PYTHONPATH=build-py/python /usr/bin/python3 python/tools/interop_check.py \
        --cli build-py/vdbrecon --out out/interop

Exit status 0 when every check passed. Needs python3-openvdb, libopenvdb-tools and blender.
"""
import argparse
import json
import math
import pathlib
import shutil
import subprocess
import sys
import time

import numpy as np

import vdbrecon

HERE = pathlib.Path(__file__).resolve().parent
SOURCE_DIR = HERE.parents[1]
GRIDS = {"sdf": ("FloatGrid", "level set"), "weight": ("FloatGrid", "unknown"),
         "nearest": ("Vec3SGrid", "unknown"), "density": ("FloatGrid", "fog volume"),
         "color": ("Vec3SGrid", "unknown")}
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


def vdb_print(path):
    out = subprocess.run(["vdb_print", "-l", str(path)], capture_output=True, text=True,
                         check=True).stdout
    print("\n".join(l for l in out.splitlines()
                    if l.startswith(("Name:", "  Type:", "  Number of active voxels", "  class:",
                                     "  file_compression", "creator"))))
    for name, (_, grid_class) in GRIDS.items():
        check(f"Name: {name}\n" in out, f"vdb_print lists '{name}'")
    check(out.count("class: level set") == 1, "vdb_print: sdf is a level set")
    check(out.count("class: fog volume") == 1, "vdb_print: density is a fog volume")


def pyopenvdb_check(path):
    import pyopenvdb
    grids, meta = pyopenvdb.readAll(str(path))
    ours = vdbrecon.read_volume(path)
    check(sorted(g.name for g in grids) == sorted(GRIDS),
          f"pyopenvdb grid names {[g.name for g in grids]}")
    for g in grids:
        cls, grid_class = GRIDS[g.name]
        coords, values = ours.to_arrays(g.name)
        acc = g.getConstAccessor()
        got = np.array([acc.getValue(tuple(int(x) for x in c)) for c in coords])
        check(type(g).__name__ == cls and g.gridClass == grid_class and
              g.activeVoxelCount() == len(coords) and np.array_equal(got, values),
              f"pyopenvdb {g.name}: {type(g).__name__}, '{g.gridClass}', "
              f"{g.activeVoxelCount()} active voxels, every value equal")
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cli", required=True)
    ap.add_argument("--out", default="out/interop")
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--no-blender", action="store_true")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # A coloured sphere, radius 0.5, voxel 0.02: closed, so vdbrecon trims nothing.
    points, normals = sphere(40000, 0.5)
    colors = (0.5 + 0.5 * normals).astype(np.float32)
    src = out / "ball_points.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points, normals, colors))
    subprocess.run([args.cli, src, "-o", out / "ball.ply", "--voxel", "0.02", "-q"], check=True)
    vdb = out / "ball.splat.vdb"
    mesh = vdbrecon.read_mesh(out / "ball.ply")
    print(f"vdbrecon: {vdb}, mesh {len(mesh.vertices)} vertices, {len(mesh.faces)} triangles")

    print("\n== vdb_print -l")
    vdb_print(vdb)
    print("== pyopenvdb")
    pyopenvdb_check(vdb)
    if args.no_blender or shutil.which("blender") is None:
        print("== blender: skipped")
    else:
        print("== blender")
        info = blender(vdb, (out / "ball_density.png").resolve(), args.samples)
        if info:
            names = {g["name"]: g for g in info["grids"]}
            check(set(names) == set(GRIDS), f"blender sees grids {sorted(names)}")
            check(names.get("density", {}).get("data_type") == "FLOAT", "density is FLOAT")
            b = info["mesh"]
            check(b["triangles"] == len(mesh.faces),
                  f"VOLUME_TO_MESH: {b['polygons']} polygons = {b['triangles']} triangles, "
                  f"vdbrecon: {len(mesh.faces)} triangles")
            half = 0.5 * 0.02  # Blender's cell-centred voxels shift its mesh by +voxel/2
            lo = np.array(b["bbox_min"]) - half
            hi = np.array(b["bbox_max"]) - half
            vlo, vhi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
            err = max(np.abs(lo - vlo).max(), np.abs(hi - vhi).max())
            check(err < 1e-4, f"bounding boxes agree within {err:.2e} (blender {lo.round(4)}.."
                  f"{hi.round(4)}, vdbrecon {vlo.round(4)}..{vhi.round(4)})")

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
