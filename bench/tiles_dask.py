#!/usr/bin/python3
"""vdbrecon.distributed on a local Dask cluster against the CLI's --tile run: wall time of
each (best of REPEAT) and whether the files are the same bytes.

    PYTHONPATH=build/python bench/tiles_dask.py INPUT VOXEL TILE [WORKERS=2] [REPEAT=3]
"""
import logging
import os
import subprocess
import sys
import tempfile
import time

import distributed

import vdbrecon.distributed


def main():
    src, voxel, tile = sys.argv[1], sys.argv[2], int(sys.argv[3])
    workers = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    repeat = int(sys.argv[5]) if len(sys.argv) > 5 else 3
    cli = os.path.join(os.path.dirname(vdbrecon.__file__), "..", "..", "vdbrecon")
    out = tempfile.mkdtemp(prefix="tiles_dask_")
    best_cli = best_dask = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        subprocess.run([cli, src, "-o", f"{out}/cli.ply", "--voxel", voxel, "--tile", str(tile),
                        "-q"], check=True)
        best_cli = min(best_cli, time.perf_counter() - t)
    with distributed.Client(distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.ERROR)) as client:
        for _ in range(repeat):
            t = time.perf_counter()
            r = vdbrecon.distributed.run(src, f"{out}/dask.ply", client=client, tile=tile,
                                         voxel=float(voxel))
            best_dask = min(best_dask, time.perf_counter() - t)
    same = open(f"{out}/cli.ply", "rb").read() == open(f"{out}/dask.ply", "rb").read()
    print(f"| {os.path.basename(src)} | {voxel} | {tile} | {r.result.tiles} | {best_cli:.2f} | "
          f"{best_dask:.2f} ({workers} workers x 1 thread) | {'same bytes' if same else 'DIFFERENT'} |")


if __name__ == "__main__":
    main()
