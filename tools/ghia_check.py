# Independent check of a cavity run against Ghia et al. (1982), sharing no code with gpm:
# reads OUT/profile_u.csv and OUT/profile_v.csv and the tables (default: data/), interpolates
# linearly, and prints RMS and max errors over the interior points (lid-speed units).
# usage: python3 tools/ghia_check.py OUT RE [TABLE_DIR]
import csv,sys,math
def table(path):
    rows=[l for l in open(path) if not l.startswith('#') and l.strip()]
    hdr=rows[0].strip().split(','); out=[]
    for l in rows[1:]:
        v=l.strip().split(','); out.append((float(v[0]),float(v[1])))
    return out
def prof(path):
    r=list(csv.reader(open(path)))[1:]
    pts=sorted((float(a),float(b)) for a,b in r)
    return pts
def interp(p,q):
    for k in range(1,len(p)):
        if p[k][0]>=q:
            (x0,y0),(x1,y1)=p[k-1],p[k]
            t=(q-x0)/(x1-x0) if x1>x0 else 0
            return y0+t*(y1-y0)
    return p[-1][1]
d,re=sys.argv[1],sys.argv[2]
tables=sys.argv[3] if len(sys.argv)>3 else 'data'
for name,f in [('u','u_vertical'),('v','v_horizontal')]:
    g=[(x,v) for x,v in table(f'{tables}/ghia1982_re{re}_{f}.csv') if 0<x<1]
    p=prof(f'{d}/profile_{name}.csv')
    e=[interp(p,x)-v for x,v in g]
    print(f'{d} {name}: {len(e)} interior points, RMS {math.sqrt(sum(a*a for a in e)/len(e)):.4%} max {max(abs(a) for a in e):.4%}')
