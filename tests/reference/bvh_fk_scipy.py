# Independent forward kinematics of a BVH clip with scipy: the reference values of
# tests/anim.rs. Usage: python3 bvh_fk_scipy.py FILE.bvh FRAME JOINT_NAME...
# (intrinsic rotations in channel order, translation = offset + position channels).
import sys, numpy as np
from scipy.spatial.transform import Rotation as R
toks=open(sys.argv[1]).read().split('MOTION')[0].split()
joints=[];stack=[];i=0
while i<len(toks):
    t=toks[i]
    if t in('ROOT','JOINT'):
        joints.append(dict(name=toks[i+1],parent=stack[-1] if stack else None,ch=[]));stack.append(len(joints)-1);i+=3;continue
    if t=='End':
        p=stack[-1];joints.append(dict(name=joints[p]['name']+'_end',parent=p,ch=[]));stack.append(len(joints)-1);i+=3;continue
    if t=='OFFSET': joints[stack[-1]]['off']=np.array([float(x) for x in toks[i+1:i+4]]);i+=4;continue
    if t=='CHANNELS':
        n=int(toks[i+1]);joints[stack[-1]]['ch']=toks[i+2:i+2+n];i+=2+n;continue
    if t=='}': stack.pop()
    i+=1
lines=open(sys.argv[1]).read().split('MOTION')[1].strip().splitlines()
k=int(sys.argv[2]); vals=[float(x) for x in lines[2+k].split()]
at=0;W=[]
for j in joints:
    t=j['off'].copy(); order='';ang=[]
    for c in j['ch']:
        v=vals[at];at+=1
        if c.endswith('position'): t['XYZ'.index(c[0])]+=v
        else: order+=c[0];ang.append(v)
    r=R.from_euler(order,ang,degrees=True) if order else R.identity()
    if j['parent'] is None: W.append((r,t))
    else:
        pr,pt=W[j['parent']]; W.append((pr*r,pt+pr.apply(t)))
for n in sys.argv[3:]:
    idx=[j['name'] for j in joints].index(n); print(n, repr(list(W[idx][1])))
