#!/usr/bin/python3
"""Markdown tables from the rows bench/harness.sh collects (one tab-separated line per run:
dataset, method, setting, status, wall s, CPU s, peak RSS MB, log, eval JSON or '-', extra:
'scored' or 'topology' for compare, the point count for scaling).

    table.py compare ROWS   time, memory, topology and scores against the reference, per run;
                            'x vdb' is the wall time over that of the dataset's first
                            `vdbrecon vdb` row (same invocation, same machine state)
    table.py scaling ROWS   time and memory against points and threads (extra = points),
                            with vdbrecon's per-stage times from its log
"""
import json
import re
import sys


def read_rows(path):
    rows = []
    with open(path) as f:
        for line in f:
            c = line.rstrip("\n").split("\t")
            rows.append(dict(dataset=c[0], method=c[1], setting=c[2], status=c[3],
                             wall=float(c[4]), cpu=float(c[5]), rss=int(c[6]), log=c[7],
                             eval=json.load(open(c[8])) if c[8] != "-" else None, extra=c[9]))
    return rows


def table(header, lines):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(x) for x in line) + " |" for line in lines]
    return "\n".join(out)


def topology(e):
    t = e["recon"]
    return [t["faces"], t["components"], t["boundary_edges"], t["nonmanifold_edges"]]


def scores(e, scored):
    """acc, comp, Chamfer (um) and F at the two taus, or dashes without a reference."""
    if not scored:
        return ["–"] * 5
    f = e["fscore"]
    return ["%.1f" % (e["accuracy"] * 1e6), "%.1f" % (e["completeness"] * 1e6),
            "%.1f" % (e["chamfer_l1"] * 1e6), "%.4f" % f[0]["fscore"], "%.4f" % f[1]["fscore"]]


def compare(rows):
    base = {}
    for r in rows:
        if r["method"] == "vdbrecon vdb" and r["status"] == "ok":
            base.setdefault(r["dataset"], r["wall"])
    lines = []
    for r in rows:
        ratio = "%.1f" % (r["wall"] / base[r["dataset"]]) if r["dataset"] in base else "–"
        head = [r["dataset"], r["method"], r["setting"], "%.2f" % r["wall"], ratio,
                "%.2f" % r["cpu"], r["rss"]]
        if r["eval"] is None:
            lines.append(head + [r["status"]] + ["–"] * 8)
        else:
            lines.append(head + topology(r["eval"]) + scores(r["eval"], r["extra"] == "scored"))
    print(table(["dataset", "method", "setting", "wall s", "x vdb", "CPU s", "peak RSS MB",
                 "faces", "comps", "boundary edges", "non-manifold edges", "acc um", "comp um",
                 "Chamfer um", "F@0.5mm", "F@1mm"], lines))


def stage_times(log, names):
    try:
        text = open(log).read()
    except OSError:
        return ["–"] * len(names)
    t = {m[0].strip(): m[1] for m in re.findall(r"([a-z ()]+) ([0-9.]+) s,", text)}
    return [t.get(n, "–") for n in names]


def log_memory(log):
    """(voxel, points MB, grids MB, start-up MB) from vdbrecon's log, None where missing."""
    try:
        text = open(log).read()
    except OSError:
        return None, None, None, None
    voxel = re.search(r"vdbrecon: voxel ([0-9.e+-]+)", text)
    points = re.search(r"rows \([^)]*\), ([0-9.]+) MB in memory", text)
    # The grids written to the .vdb (the splat's and the density grid made for the file), else
    # (older logs, or --no-vdb) the splat's grids.
    grids = re.search(r"grids written ([0-9.]+) MB", text) or re.search(
        r"grids ([0-9.]+) MB in memory", text)
    # What the process held before reading anything: the executable and shared libraries.
    startup = re.search(r"above the ([0-9.]+) MB at start-up", text)
    return tuple(float(m[1]) if m else None for m in (voxel, points, grids, startup))


def scaling(rows):
    wall = {(r["dataset"], r["method"]): r["wall"] for r in rows if r["status"] == "ok"}
    splat = {(r["dataset"], r["method"]): stage_times(r["log"], ["splat"])[0] for r in rows
             if r["status"] == "ok"}
    lines = []
    for r in rows:
        points = int(r["extra"])
        one = wall.get((r["dataset"], "1"))
        fixed = r["method"] in ("1", "2")  # the thread rows at the fixed voxel
        speedup = "%.2f" % (one / r["wall"]) if one and fixed and r["status"] == "ok" else "–"
        s1, s = splat.get((r["dataset"], "1"), "–"), splat.get((r["dataset"], r["method"]), "–")
        splat_speedup = "%.2f" % (float(s1) / float(s)) if fixed and "–" not in (s1, s) else "–"
        voxel, points_mb, grids_mb, startup_mb = log_memory(r["log"])
        data_mb = points_mb + grids_mb if points_mb and grids_mb else None
        ratio = "%.2f" % (r["rss"] / data_mb) if data_mb else "–"
        above = "%.2f" % ((r["rss"] - startup_mb) / data_mb) if data_mb and startup_mb else "–"
        head = [r["dataset"], "{:,}".format(points), r["method"],
                "%.3g" % (voxel * 1e3) if voxel else "–", "%.2f" % r["wall"],
                "%.2f" % r["cpu"], r["rss"], "%d" % startup_mb if startup_mb else "–",
                "%.1f" % grids_mb if grids_mb else "–",
                "%.1f" % points_mb if points_mb else "–", ratio, above]
        stages = stage_times(r["log"], ["read", "outliers", "normals", "splat", "mesh"])
        head += stages
        per_point = "–"
        if "–" not in stages:
            per_point = "%.2f" % (sum(float(t) for t in stages) / points * 1e6)
        head += ["%.2f" % (r["wall"] / points * 1e6), per_point, speedup, splat_speedup]
        if r["eval"] is None:
            lines.append(head + [r["status"], "–", "–"])
        else:
            e = r["eval"]
            lines.append(head + [e["recon"]["faces"], "%.4f" % e["fscore"][0]["fscore"],
                                 "%.1f" % (e["chamfer_l1"] * 1e6)])
    print(table(["input", "points", "threads", "voxel mm", "wall s", "CPU s", "peak RSS MB",
                 "start-up MB", "grids MB", "points MB", "peak / (grids + points)",
                 "(peak - start-up) / (grids + points)", "read", "outliers",
                 "normals", "splat", "mesh", "wall us/point", "stages us/point",
                 "speed-up vs 1 thread", "splat speed-up", "faces", "F@0.5mm", "Chamfer um"],
                lines))


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("compare", "scaling"):
        sys.exit(__doc__)
    (compare if sys.argv[1] == "compare" else scaling)(read_rows(sys.argv[2]))
