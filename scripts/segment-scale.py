#!/usr/bin/env python3
"""Scale of a trajectory's segments against the ground truth.

usage: segment-scale.py TRAJECTORY.tum GROUNDTRUTH.txt B0,B1,...,Bn

Aligns the estimate to the ground truth by a similarity (Umeyama, all poses
matched by timestamp), then prints for each segment [Bi, Bi+1] of pose
indices the path length of the estimate over that of the truth: 1 everywhere
is a scale that holds; a step between segments is scale drift (issue 20).
Needs numpy (the peer venv's).
"""
import numpy as np, sys
def read(p):
    d={}
    for l in open(p):
        if l.startswith('#') or not l.strip(): continue
        v=[float(x) for x in l.split()]; d[round(v[0],4)]=np.array(v[1:4])
    return d
est=read(sys.argv[1]); gt=read(sys.argv[2])
keys=sorted(k for k in est if k in gt)
E=np.array([est[k] for k in keys]); G=np.array([gt[k] for k in keys])
# Umeyama sim3 E->G
me,mg=E.mean(0),G.mean(0); X=E-me; Y=G-mg
U,S,Vt=np.linalg.svd(Y.T@X/len(E)); D=np.eye(3)
if np.linalg.det(U@Vt)<0: D[2,2]=-1
R=U@D@Vt; s=np.trace(np.diag(S)@D)/X.var(0).sum()
A=(s*(R@X.T)).T+mg
print("frames",len(keys),"ATE %.3f m"%np.sqrt(((A-G)**2).sum(1).mean()))
bounds=[int(b) for b in sys.argv[3].split(',')]
segs=list(zip(bounds[:-1],bounds[1:]))
out=[]
for a,b in segs:
    b=min(b,len(keys)-1)
    le=np.linalg.norm(np.diff(A[a:b+1],axis=0),axis=1).sum(); lg=np.linalg.norm(np.diff(G[a:b+1],axis=0),axis=1).sum()
    out.append("%d-%d:%.3f"%(a,b,le/lg))
print("seg scale", " ".join(out))

