#!/usr/bin/python3
"""Mesh statistics of one reconstructed scan, for bench/scenes.sh (numpy only, no scipy).

  bench/scene_stats.py header
      prints the markdown table's header (two lines).
  bench/scene_stats.py row NAME MESH.ply INPUT VOXEL WALL [STATUS]
      prints one markdown row: faces, pieces (edge-connected face components), mesh area, the
      share of the area whose face normal cross(b - a, c - a) has z < 0, the share of the
      input points within 1 voxel of the mesh (exact point-to-triangle distance) and WALL.
      INPUT is a PLY (binary little/big endian or ASCII; x y z among the vertex properties) or
      a LAS file (1.0-1.4, any point format: x y z are the int32 triple at the start of every
      record, scaled by the header's scale and offset). With STATUS other than "ok", or no
      MESH, the row carries STATUS and dashes.
  bench/scene_stats.py selftest
      checks the point-to-triangle distance against dense sampling and the piece count.

Frames: vdbrecon keeps far-away input in a local frame but writes its PLY in the input's frame
(write_ply adds the origin back and stores x y z as doubles), so the mesh and the points are
compared as read; both are shifted by one common point before any arithmetic, so float64 keeps
its precision at georeferenced coordinates. A mesh whose box lies nowhere near the points' box
is reported (frame mismatch) instead of being scored.

Distance: a point counts when some triangle lies within VOXEL of it (<=). A hash grid of cell
VOXEL answers first "is a mesh vertex within VOXEL?" (sufficient); the points left are checked
exactly against every triangle whose bounding box touches their 3x3x3 cells.
"""
import sys
import numpy as np

PLY_TYPES = {
    'char': 'i1', 'int8': 'i1', 'uchar': 'u1', 'uint8': 'u1',
    'short': 'i2', 'int16': 'i2', 'ushort': 'u2', 'uint16': 'u2',
    'int': 'i4', 'int32': 'i4', 'uint': 'u4', 'uint32': 'u4',
    'float': 'f4', 'float32': 'f4', 'double': 'f8', 'float64': 'f8',
}


def read_ply(path):
    """(vertices as float64 N x 3, triangles as int64 M x 3 or None)."""
    data = open(path, 'rb').read()
    end = data.index(b'end_header')
    end = data.index(b'\n', end) + 1
    lines = data[:end].decode('ascii', 'replace').splitlines()
    fmt = lines[1].split()[1]
    elements = []  # [name, count, [(prop name, type) | (name, ('list', count type, item type))]]
    for line in lines:
        w = line.split()
        if not w:
            continue
        if w[0] == 'element':
            elements.append([w[1], int(w[2]), []])
        elif w[0] == 'property':
            if w[1] == 'list':
                elements[-1][2].append((w[4], ('list', w[2], w[3])))
            else:
                elements[-1][2].append((w[2], w[1]))
    verts = faces = None
    if fmt == 'ascii':
        rows = data[end:].decode('ascii').split('\n')
        at = 0
        for name, count, props in elements:
            block = rows[at:at + count]
            at += count
            if name == 'vertex':
                names = [p[0] for p in props]
                cols = [names.index(a) for a in 'xyz']
                verts = np.array([[float(r.split()[c]) for c in cols] for r in block])
            elif name == 'face':
                f = [list(map(int, r.split())) for r in block]
                faces = triangulate([r[1:1 + r[0]] for r in f])
        return verts, faces
    end_char = '<' if fmt == 'binary_little_endian' else '>'
    pos = end
    for name, count, props in elements:
        lists = [p for p in props if isinstance(p[1], tuple)]
        if not lists:
            dt = np.dtype([(p[0], end_char + PLY_TYPES[p[1]]) for p in props])
            a = np.frombuffer(data, dtype=dt, count=count, offset=pos)
            pos += dt.itemsize * count
            if name == 'vertex':
                verts = np.stack([a['x'], a['y'], a['z']], 1).astype(np.float64)
            continue
        # An element with a list: the common fixed layout (one 'list uchar int' of 3, maybe
        # scalars after it) is read in one go; anything else row by row.
        if name == 'face' and len(lists) == 1 and props[0] is lists[0]:
            _, (_, ct, it) = lists[0]
            rest = [(p[0], end_char + PLY_TYPES[p[1]]) for p in props[1:]]
            dt = np.dtype([('n', end_char + PLY_TYPES[ct]), ('v', end_char + PLY_TYPES[it], 3)]
                          + rest)
            if count == 0:
                faces = np.zeros((0, 3), np.int64)
                continue
            a = np.frombuffer(data, dtype=dt, count=count, offset=pos)
            if (a['n'] == 3).all():
                faces = a['v'].astype(np.int64)
                pos += dt.itemsize * count
                continue
        poly = []
        for _ in range(count):
            row = None
            for pname, t in props:
                if isinstance(t, tuple):
                    ct = np.dtype(end_char + PLY_TYPES[t[1]])
                    n = int(np.frombuffer(data, ct, 1, pos)[0])
                    pos += ct.itemsize
                    it = np.dtype(end_char + PLY_TYPES[t[2]])
                    vals = np.frombuffer(data, it, n, pos)
                    pos += it.itemsize * n
                    if pname in ('vertex_indices', 'vertex_index'):
                        row = vals.tolist()
                else:
                    pos += np.dtype(PLY_TYPES[t]).itemsize
            if name == 'face':
                poly.append(row)
        if name == 'face':
            faces = triangulate(poly)
    return verts, faces


def triangulate(polys):
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.array(tris, np.int64).reshape(-1, 3)


def read_las(path):
    """Points of a LAS file (float64, in the file's coordinate units)."""
    data = open(path, 'rb').read()
    if data[:4] != b'LASF':
        raise ValueError(path + ': not a LAS file')
    major, minor = data[24], data[25]
    offset = int(np.frombuffer(data, '<u4', 1, 96)[0])
    record = int(np.frombuffer(data, '<u2', 1, 105)[0])
    count = int(np.frombuffer(data, '<u4', 1, 107)[0])
    if count == 0 and (major, minor) >= (1, 4):
        count = int(np.frombuffer(data, '<u8', 1, 247)[0])  # LAS 1.4 64-bit count
    scale = np.frombuffer(data, '<f8', 3, 131)
    shift = np.frombuffer(data, '<f8', 3, 155)
    count = min(count, (len(data) - offset) // record)
    dt = np.dtype({'names': ['xyz'], 'formats': [('<i4', 3)], 'itemsize': record})
    raw = np.frombuffer(data, dt, count, offset)['xyz'].astype(np.float64)
    return raw * scale + shift


def read_points(path):
    with open(path, 'rb') as f:
        magic = f.read(4)
    p = read_las(path) if magic == b'LASF' else read_ply(path)[0]
    return p[np.isfinite(p).all(1)]


# --- hash grid ---------------------------------------------------------------------------------

class Grid:
    """Cells of edge h keyed as one int64, items sorted by key."""

    def __init__(self, lo, h, dims):
        self.lo, self.h, self.dims = lo, h, dims  # dims: cells per axis incl. a margin of 2

    def cell(self, p):
        return np.floor((p - self.lo) / self.h).astype(np.int64) + 1

    def key(self, c):
        return (c[:, 0] * self.dims[1] + c[:, 1]) * self.dims[2] + c[:, 2]

    def build(self, keys, items):
        order = np.argsort(keys, kind='stable')
        self.keys, self.items = keys[order], items[order]
        self.ukeys, self.start = np.unique(self.keys, return_index=True)
        self.stop = np.append(self.start[1:], len(self.keys))

    def pairs(self, qcell, qindex, offsets):
        """(query index, item) for every item in the cells qcell + each offset, in chunks."""
        for off in offsets:
            k = self.key(qcell + off)
            j = np.searchsorted(self.ukeys, k)
            j = np.minimum(j, len(self.ukeys) - 1)
            hit = self.ukeys[j] == k
            q, j = qindex[hit], j[hit]
            n = self.stop[j] - self.start[j]
            if len(n) == 0:
                continue
            qq = np.repeat(q, n)
            base = np.repeat(self.start[j] - np.cumsum(n) + n, n)
            items = self.items[base + np.arange(n.sum())]
            yield qq, items


OFFSETS = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)])


def point_triangle_distance2(p, a, b, c):
    """Squared distance of points p to triangles (a, b, c), rows paired (Ericson 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide='ignore', invalid='ignore'):
        v = vb / denom
        w = vc / denom
        q = a + ab * v[:, None] + ac * w[:, None]  # interior
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # Edge regions, then vertex regions (the vertex tests win, as in Ericson's order).
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    q[m] = a[m] + ab[m] * t_ab[m, None]
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    q[m] = a[m] + ac[m] * t_ac[m, None]
    m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    q[m] = b[m] + (c[m] - b[m]) * t_bc[m, None]
    m = (d1 <= 0) & (d2 <= 0)
    q[m] = a[m]
    m = (d3 >= 0) & (d4 <= d3)
    q[m] = b[m]
    m = (d6 >= 0) & (d5 <= d6)
    q[m] = c[m]
    # Degenerate (zero-area) triangles: the nearest of the three edges' points is not worth
    # the code; their vertices are covered by the vertex pass and their neighbours.
    bad = ~np.isfinite(q).all(1)
    q[bad] = a[bad]
    return ((p - q) ** 2).sum(1)


def near_share(points, verts, tris, r, chunk=2_000_000):
    """Share of points within r of the mesh (exact), and of points within r of a vertex."""
    n = len(points)
    if n == 0 or len(tris) == 0:
        return 0.0, 0.0
    lo = np.minimum(points.min(0), verts.min(0)) - r
    hi = np.maximum(points.max(0), verts.max(0)) + r
    dims = (np.floor((hi - lo) / r).astype(np.int64) + 4)
    if np.prod(dims.astype(float)) > 9e18:
        raise ValueError('grid too large for int64 keys')
    g = Grid(lo, r, dims)
    near = np.zeros(n, bool)
    pc = g.cell(points)
    # 1. a vertex within r (sufficient)
    g.build(g.key(g.cell(verts)), np.arange(len(verts)))
    idx = np.arange(n)
    for off in OFFSETS:
        todo = idx[~near]
        if len(todo) == 0:
            break
        for qq, vv in g.pairs(pc[todo], todo, [off]):
            d2 = ((points[qq] - verts[vv]) ** 2).sum(1)
            near[qq[d2 <= r * r]] = True
    vertex_share = near.mean()
    # 2. the rest: every triangle whose box overlaps one of the 27 cells around the point
    todo = idx[~near]
    if len(todo):
        tv = verts[tris]
        c0, c1 = g.cell(tv.min(1)), g.cell(tv.max(1))
        ext = c1 - c0 + 1
        cnt = ext.prod(1)
        t = np.repeat(np.arange(len(tris)), cnt)
        k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        e = ext[t]
        cells = c0[t] + np.stack([k // (e[:, 1] * e[:, 2]), (k // e[:, 2]) % e[:, 1], k % e[:, 2]], 1)
        g.build(g.key(cells), t)
        for off in OFFSETS:
            todo = idx[~near]
            if len(todo) == 0:
                break
            for qq, tt in g.pairs(pc[todo], todo, [off]):
                for s in range(0, len(qq), chunk):
                    q, f = qq[s:s + chunk], tt[s:s + chunk]
                    d2 = point_triangle_distance2(points[q], tv[f, 0], tv[f, 1], tv[f, 2])
                    near[q[d2 <= r * r]] = True
    return near.mean(), vertex_share


def pieces(tris):
    """Edge-connected face components (faces sharing an edge, in any orientation)."""
    m = len(tris)
    if m == 0:
        return 0
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e.sort(1)
    face = np.tile(np.arange(m), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, face = e[order], face[order]
    same = (e[1:] == e[:-1]).all(1)
    a, b = face[:-1][same], face[1:][same]  # consecutive faces on the same edge: a chain
    parent = np.arange(m)
    while True:
        pa, pb = parent[a], parent[b]
        if (pa == pb).all():
            break
        np.minimum.at(parent, np.maximum(pa, pb), np.minimum(pa, pb))
        while True:
            pp = parent[parent]
            if (pp == parent).all():
                break
            parent = pp
    return len(np.unique(parent))


def stats(mesh_path, input_path, voxel):
    verts, tris = read_ply(mesh_path)
    points = read_points(input_path)
    if tris is None:
        tris = np.zeros((0, 3), np.int64)
    # one common shift, so georeferenced coordinates keep their precision in float64
    shift = np.floor(points.mean(0)) if len(points) else np.zeros(3)
    points = points - shift
    verts = verts - shift
    out = {'faces': len(tris), 'points': len(points), 'vertices': len(verts)}
    if len(tris) == 0:
        out.update(pieces=0, area=0.0, down=float('nan'), near=0.0, near_vertex=0.0, frame='empty')
        return out
    # frame check: the mesh's box must overlap the points' box (grown by 10 %)
    plo, phi = points.min(0), points.max(0)
    grow = 0.1 * (phi - plo) + voxel
    vlo, vhi = verts.min(0), verts.max(0)
    out['frame'] = 'ok' if ((vlo <= phi + grow) & (vhi >= plo - grow)).all() else 'MISMATCH'
    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    n = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(n, axis=1)
    out['area'] = area.sum()
    out['down'] = area[n[:, 2] < 0].sum() / out['area'] if out['area'] > 0 else float('nan')
    out['pieces'] = pieces(tris)
    if out['frame'] == 'ok':
        out['near'], out['near_vertex'] = near_share(points, verts, tris, voxel)
    else:
        out['near'] = out['near_vertex'] = float('nan')
    return out


HEADER = ("| scan | voxel | input points | faces | pieces | mesh area (input units²) "
          "| area facing down (face normal z < 0) "
          "| input points within 1 voxel of the mesh: exact point-to-triangle (in brackets: of a mesh vertex) "
          "| wall s |\n|---|---|---|---|---|---|---|---|---|")


def fmt_int(v):
    return f"{v:,}"


def row(name, mesh, inp, voxel, wall, status='ok'):
    if status != 'ok':
        return f"| {name} | {voxel:g} | - | - | - | - | - | - | {wall} ({status}) |"
    s = stats(mesh, inp, voxel)
    near = (f"{s['near'] * 100:.2f} % ({s['near_vertex'] * 100:.2f} %)"
            if s['frame'] == 'ok' else f"frame {s['frame']}")
    return (f"| {name} | {voxel:g} | {fmt_int(s['points'])} | {fmt_int(s['faces'])} "
            f"| {fmt_int(s['pieces'])} | {s['area']:.4g} | {s['down'] * 100:.1f} % | {near} | {wall} |")


def selftest():
    rng = np.random.default_rng(1)
    tv = rng.normal(size=(200, 3, 3))
    tv[:20, 2] = tv[:20, 0] + 1e-3 * rng.normal(size=(20, 3))  # thin triangles
    p = rng.normal(size=(200, 3)) * 2
    d2 = point_triangle_distance2(p, tv[:, 0], tv[:, 1], tv[:, 2])
    u = rng.random((200000, 2))
    flip = u.sum(1) > 1
    u[flip] = 1 - u[flip]
    worst = 0.0
    for i in range(len(p)):
        s = tv[i, 0] + u[:, :1] * (tv[i, 1] - tv[i, 0]) + u[:, 1:] * (tv[i, 2] - tv[i, 0])
        ref = np.sqrt(((s - p[i]) ** 2).sum(1).min())
        got = np.sqrt(d2[i])
        assert got <= ref + 1e-9, (i, got, ref)  # never beyond the sampled surface
        worst = max(worst, ref - got)
    assert worst < 2e-2, worst
    # two squares sharing only a vertex (a bow tie) are two pieces; a strip is one
    t = np.array([[0, 1, 2], [0, 2, 3], [2, 4, 5], [2, 5, 6], [7, 8, 9], [8, 9, 10]])
    assert pieces(t) == 3, pieces(t)
    # near_share against brute force
    verts = rng.random((300, 3))
    tris = rng.integers(0, 300, (400, 3))
    pts = rng.random((2000, 3)) * 1.4 - 0.2
    r = 0.03
    got, _ = near_share(pts, verts, tris, r)
    best = np.full(len(pts), np.inf)
    for f in range(len(tris)):
        a, b, c = (np.repeat(verts[tris[f, k]][None], len(pts), 0) for k in range(3))
        best = np.minimum(best, point_triangle_distance2(pts, a, b, c))
    ref = (best <= r * r).mean()
    assert abs(got - ref) < 1e-12, (got, ref)
    print(f"selftest ok (worst under-estimate vs sampling {worst:.2e}, near {got:.4f})")


def main(argv):
    if len(argv) >= 2 and argv[1] == 'header':
        print(HEADER)
    elif len(argv) >= 2 and argv[1] == 'selftest':
        selftest()
    elif len(argv) in (7, 8) and argv[1] == 'row':
        print(row(argv[2], argv[3], argv[4], float(argv[5]), argv[6], *argv[7:]))
    else:
        sys.exit(__doc__)


if __name__ == '__main__':
    main(sys.argv)
