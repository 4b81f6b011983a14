#!/usr/bin/env python3
"""How well 1 / z polynomial in the normalised image coordinates, fitted to a
curved front's rim alone, gives the front inside it (seventy-third entry):
a vertical cylinder of radius 1.5 through the origin, its glass |y| <= 1,
0.2 <= z <= 1.2, seen from 3.5 away at 0, 25 and 50 degrees off its axis;
the rim sampled exactly, 1 / z fitted with degree 1 (a plane), 2 and 3,
then the normal error (median, max, degrees) and the depth error (median
share) at 375 points inside. Prints one row per degree."""
import numpy as np
R=1.5
def frame(eye, target):
    f=np.array(target)-eye; f/=np.linalg.norm(f); up=np.array([0,0,1.]); r=np.cross(f,up); r/=np.linalg.norm(r); u=np.cross(r,f)
    return r,u,f
def run(ang, deg):
    a=np.radians(ang); eye=np.array([3.5*np.cos(a),3.5*np.sin(a),0.5]); r,u,f=frame(eye,[0,0,0.7])
    def surf(y,z): return np.array([np.sqrt(R*R-y*y)-R,y,z])
    def tocam(P):
        d=P-eye; Z=d@f; return np.array([(d@r)/Z,(d@u)/Z,1/Z])
    # rim
    pts=[]
    for s in np.linspace(-1,1,60):
        pts+= [tocam(surf(s,0.2)),tocam(surf(s,1.2))]
    for s in np.linspace(0.2,1.2,30):
        pts+= [tocam(surf(-1,s)),tocam(surf(1,s))]
    pts=np.array(pts)
    def feats(x,y):
        fs=[np.ones_like(x),x,y]
        if deg>=2: fs+=[x*x,x*y,y*y]
        if deg>=3: fs+=[x**3,x*x*y,x*y*y,y**3]
        return np.stack(fs,-1)
    c,*_=np.linalg.lstsq(feats(pts[:,0],pts[:,1]),pts[:,2],rcond=None)
    # interior
    errs=[]; offs=[]
    for yy in np.linspace(-0.95,0.95,25):
        for zz in np.linspace(0.25,1.15,15):
            P=surf(yy,zz); q=tocam(P); x,y=q[0],q[1]
            w=feats(np.array([x]),np.array([y]))[0]@c
            # numeric gradient normal: surface point as function of (x,y)
            def pt(x,y):
                w=feats(np.array([x]),np.array([y]))[0]@c; Z=1/w
                return eye + Z*(x*r+y*u+f)
            h=1e-4
            n=np.cross(pt(x+h,y)-pt(x-h,y), pt(x,y+h)-pt(x,y-h)); n/=np.linalg.norm(n)
            tn=np.array([P[0]+R,P[1],0])/R
            errs.append(np.degrees(np.arccos(min(1,abs(n@tn)))))
            offs.append(abs(1-w/q[2]))
    return np.median(errs), np.max(errs), np.median(offs)
for deg in (1,2,3):
    cells = ["%5.1f / %5.1f deg, %.3f" % tuple(float(v) for v in run(a, deg)) for a in (0, 25, 50)]
    print("degree %d: at 0 / 25 / 50 degrees off: %s" % (deg, " | ".join(cells)))
