#!/usr/bin/env python3
"""Interleaved timing of one run over 2 MPI ranks x 1 thread against DD at 1 rank x 2 threads
(the measurement behind results/mpi): PAIRS pairs in alternating order, Taylor MODEL, STEPS
steps each; prints per pair and overall the ratio of ns per particle-step (median and a
bootstrap 95 % interval), each rank's exchange time over the wall time, with `split` the
waiting for the other rank apart (`mpm run --split-wait`), and the peak memory of both.

Usage: scripts/mpi-pair.py PAIRS MODEL STEPS [split]   (needs target/o3/mpm and mpirun)
"""
import json, os, subprocess, sys, statistics, random
mpm=os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'target', 'o3', 'mpm'); pairs=int(sys.argv[1]); model=sys.argv[2]; steps=sys.argv[3]
A=[mpm,'run','taylor','--model',model,'--strategy','dd','--threads','2','--cpus','0,1','--steps',steps,'--json','/tmp/mA.json']
B=['mpirun','--oversubscribe','--allow-run-as-root','-n','2',mpm,'run','taylor','--model',model,'--strategy','dd','--threads','1','--steps',steps,'--json','/tmp/mB.json']+(['--split-wait'] if len(sys.argv)>4 else [])
ra=[];rb=[];ratios=[];exf=[];mem=[];exmean=[];waits=[]
def go(cmd,path):
    subprocess.run(cmd,check=True,stdout=subprocess.DEVNULL,stderr=subprocess.DEVNULL); return json.load(open(path))
for i in range(pairs):
    order=[(A,'/tmp/mA.json'),(B,'/tmp/mB.json')]
    if i%2: order.reverse()
    res={}
    for c,p in order: res[p]=go(c,p)
    a=res['/tmp/mA.json']; b=res['/tmp/mB.json']
    x=a['ns_per_particle_step']; y=b['ns_per_particle_step']
    ra.append(x); rb.append(y); ratios.append(y/x)
    wall=b['steady_s_per_step']*b['steady_steps'] if b.get('steady_steps') else b['wall_s']
    ex=max(r['exchange']['seconds'] for r in b['ranks'])/b['wall_s']
    exm=sum(r['exchange']['seconds'] for r in b['ranks'])/len(b['ranks'])/b['wall_s']
    exmean.append(exm)
    wt=[r['exchange'].get('wait_seconds') for r in b['ranks']]
    if wt[0] is not None: waits.append(sum(wt)/len(wt)/b['wall_s'])
    exf.append(ex); mem.append((a['peak_rss_bytes'], sum(r['peak_rss_bytes'] for r in b['ranks']), [r['peak_rss_bytes'] for r in b['ranks']]))
    print(f'pair {i}: DD1x2 {x:.1f} ns  2x1 {y:.1f} ns  B/A {y/x:.4f}  exchange/wall max {ex:.3f} mean {exm:.3f}',flush=True)
random.seed(1)
boots=sorted(statistics.median(random.choices(ratios,k=len(ratios))) for _ in range(4000))
print(f'B/A median {statistics.median(ratios):.4f} 95% CI [{boots[100]:.4f}, {boots[3899]:.4f}] n={pairs}; A med {statistics.median(ra):.1f} B med {statistics.median(rb):.1f}')
print(f'exchange seconds / wall: max over ranks median {statistics.median(exf):.3f} [{min(exf):.3f}, {max(exf):.3f}]; mean over ranks median {statistics.median(exmean):.3f} [{min(exmean):.3f}, {max(exmean):.3f}]')
print('wait/wall mean over ranks: median', statistics.median(waits) if waits else None, [round(w,3) for w in waits])
print('memory (R=1 DD 2 threads peak RSS, R=2 sum, per rank) MiB:', [(m[0]/2**20, m[1]/2**20, [v/2**20 for v in m[2]]) for m in mem[:2]])
