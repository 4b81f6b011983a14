#!/usr/bin/env python3
"""Does Stage I's own depth-normal disagreement tell the glass from the rest?

For each scene of a suite (`suite.py`'s layout: DATA/SCENE with test views
holding normals and masks, RUNS/SCENE/sSEED/I the Stage I run and
RUNS/SCENE/sSEED/VARIANT a Stage II run from it), reads the test renders
(`*_normal.png`, `*_depth.exr`; the Stage II run's `*_normal_refl.png`),
computes per pixel the angle between Stage I's normal and the normal of
its depth (Blender cameras, z depth), and prints its AUC for glass
against the rest, the normal MAE on and off the glass of Stage I and of
Stage II's output, and of the rule "the reflection set decides a pixel
only where the disagreement exceeds tau" (pixel means over the test
views). perf/RESULTS.md, thirty-fourth entry.

    python3 perf/journal/scripts/stage1_consistency.py DATA RUNS globe,pane [VARIANT [SEED]]

Needs numpy, pillow and mitsuba (to read the EXR depth).
"""
import numpy as np, json, sys, os, math
from PIL import Image
import mitsuba as mi
mi.set_variant('scalar_rgb')
def exr(p):
    a=np.array(mi.Bitmap(p)).astype(np.float64)
    return a[...,0] if a.ndim==3 else a
def npng(p): return np.asarray(Image.open(p)).astype(np.float64)/255*2-1
def unit(v): return v/np.maximum(np.linalg.norm(v,axis=-1,keepdims=True),1e-9)
def ang(a,b): return np.degrees(np.arccos(np.clip((unit(a)*unit(b)).sum(-1),-1,1)))
def depth_normals(d,c2w,fovx,zdepth=True):
    h,w=d.shape; f=0.5*w/math.tan(fovx/2)
    u,v=np.meshgrid(np.arange(w)+0.5,np.arange(h)+0.5)
    dirs=np.stack([(u-w/2)/f,-(v-h/2)/f,-np.ones_like(u)],-1)
    if not zdepth: dirs=unit(dirs)
    P=(dirs*d[...,None])@c2w[:3,:3].T+c2w[:3,3]
    dx=np.zeros_like(P); dy=np.zeros_like(P)
    dx[:,1:-1]=P[:,2:]-P[:,:-2]; dy[1:-1]=P[2:]-P[:-2]
    n=unit(np.cross(dx,dy))
    o=c2w[:3,3]; tocam=unit(o-P)
    n=np.where(((n*tocam).sum(-1)<0)[...,None],-n,n)
    ok=np.zeros(d.shape,bool); ok[1:-1,1:-1]=True
    ok&=(d>0); ok[1:-1,1:-1]&=(d[2:,1:-1]>0)&(d[:-2,1:-1]>0)&(d[1:-1,2:]>0)&(d[1:-1,:-2]>0)
    return n,ok
def auc(pos,neg):
    x=np.concatenate([pos,neg]); r=x.argsort().argsort()+1
    return (r[:len(pos)].sum()-len(pos)*(len(pos)+1)/2)/(len(pos)*len(neg))
if len(sys.argv) < 4:
    raise SystemExit(__doc__)
DATA, RUNS = sys.argv[1], sys.argv[2]
scenes = sys.argv[3].split(','); var = sys.argv[4] if len(sys.argv) > 4 else 'default'; seed = sys.argv[5] if len(sys.argv) > 5 else '0'
zd = True
for sc in scenes:
    data=os.path.join(DATA, sc); run=os.path.join(RUNS, sc, f's{seed}')
    t=json.load(open(f'{data}/transforms_test.json')); fov=t['camera_angle_x']
    C=[];G=[];E1=[];E2=[];NS=[];NR=[];DEC=[]
    for fr in t['frames']:
        name=os.path.basename(fr['file_path']).replace('.png','')
        c2w=np.array(fr['transform_matrix'])
        gt=np.load(f"{data}/{fr['normal_path']}") if fr['normal_path'].endswith('.npy') else np.load(f"{data}/{fr['normal_path']}")
        mask=np.asarray(Image.open(f"{data}/{fr['mask_path']}"))
        if mask.ndim==3: mask=mask[...,0]
        mask=mask>127
        d1=exr(f'{run}/I/renders/test/{name}_depth.exr')
        n1=npng(f'{run}/I/renders/test/{name}_normal.png')
        nd,ok=depth_normals(d1,c2w,fov,zd)
        c=ang(n1,nd)
        h2=f'{run}/{var}/renders/test/{name}'
        n2=npng(h2+'_normal.png'); nr=npng(h2+'_normal_refl.png'); ns=npng(h2+'_normal_scat.png')
        dec=np.abs(ang(n2,nr))<1.0  # output came from the reflection set
        gtok=np.linalg.norm(gt,axis=-1)>0.5
        sel=ok&gtok
        C.append(c[sel]);G.append(mask[sel]);E1.append(ang(n1,gt)[sel]);E2.append(ang(n2,gt)[sel]);NR.append(ang(nr,gt)[sel]);DEC.append(dec[sel])
    C=np.concatenate(C);G=np.concatenate(G);E1=np.concatenate(E1);E2=np.concatenate(E2);NR=np.concatenate(NR);DEC=np.concatenate(DEC)
    line=f'{sc}: n={len(C)} glass={G.mean():.2f} AUC(c: glass>rest)={auc(C[G],C[~G]):.2f} c glass {np.median(C[G]):.1f} rest {np.median(C[~G]):.1f}; I glass {E1[G].mean():.1f} rest {E1[~G].mean():.1f}; II glass {E2[G].mean():.1f} rest {E2[~G].mean():.1f}; decides glass {DEC[G].mean():.2f} rest {DEC[~G].mean():.2f}'
    rows=[]
    for tau in [10,20,30,45]:
        use=DEC&(C>tau)
        E=np.where(use,NR,E1)
        rows.append(f'tau{tau}: glass {E[G].mean():.1f} rest {E[~G].mean():.1f}')
    print(line); print('   '+'; '.join(rows))
