#!/usr/bin/python3
"""Precision on scans without a reference mesh: the fraction of a mesh's vertices within 1 and 2
voxels of an input point (hash grid of cell = radius). Usage: bench/near_points.py MESH.ply SCAN.ply VOXEL
Binary or ASCII PLY; x, y, z must be the first three vertex properties."""
import numpy as np, sys, collections
def ply(f):
    b=open(f,'rb').read(); i=b.index(b'end_header\n')+11; h=b[:i].decode().split('\n')
    asc='ascii' in h[1]
    ev=[l for l in h if l.startswith('element vertex')][0]; nv=int(ev.split()[2])
    props=[];inv=False
    for l in h:
        if l.startswith('element vertex'): inv=True; continue
        if l.startswith('element') : inv=False
        if inv and l.startswith('property'): props.append(l.split()[1])
    size={'float':4,'float32':4,'double':8,'uchar':1,'uint8':1,'int':4,'int32':4,'uint':4,'ushort':2,'short':2}
    dt=np.dtype([('p%d'%k,{'float':'<f4','float32':'<f4','double':'<f8','uchar':'u1','uint8':'u1','int':'<i4','int32':'<i4','uint':'<u4','ushort':'<u2','short':'<i2'}[t]) for k,t in enumerate(props)])
    if asc:
        V=np.loadtxt(f,skiprows=len(h)-1,max_rows=nv,usecols=(0,1,2))
        return V
    a=np.frombuffer(b,dtype=dt,count=nv,offset=i)
    return np.stack([a['p0'],a['p1'],a['p2']],1).astype(np.float64)
mesh=ply(sys.argv[1]); pts=ply(sys.argv[2]); vox=float(sys.argv[3])
pts=pts[np.isfinite(pts).all(1)]
for d in (1.0,2.0):
    r=d*vox; key=np.floor(pts/r).astype(np.int64)
    order=np.lexsort(key.T); key=key[order]; P=pts[order]
    uk,start=np.unique(key,axis=0,return_index=True)
    idx={tuple(k):(s,e) for k,s,e in zip(uk,start,list(start[1:])+[len(P)])}
    ok=0
    mk=np.floor(mesh/r).astype(np.int64)
    for v,k in zip(mesh,mk):
        best=False
        for dx in (-1,0,1):
            for dy in (-1,0,1):
                for dz in (-1,0,1):
                    se=idx.get((k[0]+dx,k[1]+dy,k[2]+dz))
                    if se and not best:
                        q=P[se[0]:se[1]]
                        if (((q-v)**2).sum(1)<=r*r).any(): best=True
        ok+=best
    print('within %.0f voxel: %.4f'%(d, ok/len(mesh)))
