# Self-convergence of a centre-line run, sharing no code with gpm: the RMS and max of the
# difference between two runs' profiles (OUT_A/profile_{u,v}.csv against OUT_B's), linearly
# interpolated to Ghia et al.'s 15 interior positions of each line (lid-speed units).
# usage: python3 tools/profile_diff.py OUT_A OUT_B
import csv,sys,math
Y=[0.9766,0.9688,0.9609,0.9531,0.8516,0.7344,0.6172,0.5,0.4531,0.2813,0.1719,0.1016,0.0703,0.0625,0.0547]
X=[0.9688,0.9609,0.9531,0.9453,0.9063,0.8594,0.8047,0.5,0.2344,0.2266,0.1563,0.0938,0.0781,0.0703,0.0625]
def prof(path):
    return sorted((float(a),float(b)) for a,b in list(csv.reader(open(path)))[1:])
def interp(p,q):
    for k in range(1,len(p)):
        if p[k][0]>=q:
            (x0,y0),(x1,y1)=p[k-1],p[k]
            return y0+(q-x0)/(x1-x0)*(y1-y0) if x1>x0 else y0
    return p[-1][1]
a,b=sys.argv[1],sys.argv[2]
for name,pos in [('u',Y),('v',X)]:
    pa,pb=prof(f'{a}/profile_{name}.csv'),prof(f'{b}/profile_{name}.csv')
    e=[interp(pa,q)-interp(pb,q) for q in pos]
    print(f'{a} - {b} {name}: RMS {math.sqrt(sum(x*x for x in e)/len(e)):.4f} max {max(abs(x) for x in e):.4f}')
