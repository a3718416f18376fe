"""PYTHONPATH=. python benchmarks/scratch_s37/choice_residuals.py RUN_DIR [METHOD ...] (every mde_iterNNN.pt kept).
The optimiser's curse check: each training trajectory's pour transitions predicted by the MDE that chose it (the
previous round's checkpoint), against their labels, per method (rounds 2-20)."""
import csv, sys, numpy as np, torch
import mde as M
RUN = sys.argv[1]
print("method | pours | mean label | mean predicted mu (choosing MDE) | label - mu | share label>=0.07 | of those predicted mu+2sd<0.07")
from pathlib import Path
methods = sys.argv[2:] or ["active_balanced", "active_cautious", "active_mean", "random_plan"]
seeds = sorted(int(p.name[4:]) for p in Path(RUN).glob("seed*"))
for meth in methods:
    res=[]
    for s in seeds:
        d=f"{RUN}/seed{s}/{meth}"
        cats=list(csv.DictReader(open(f"{d}/categories.csv")))
        D=torch.load(f"{d}/dataset.pt",weights_only=False); X=D["X"]; Y=D["y"]
        i=0; byit={}
        for c in cats:
            n=int(c["steps"]); byit.setdefault(int(c["iteration"]),[]).append((i,i+n)); i+=n
        for it,spans in byit.items():
            if it<2: continue
            mde=M.load(f"{d}/mde_iter{it-1:03d}.pt")
            idx=torch.cat([torch.arange(a,b) for a,b in spans])
            Xi=X[idx]; Yi=Y[idx]
            pour=(Xi[:,5]==1)
            mu,sd=mde.predict(Xi[pour])
            res.append(np.stack([Yi[pour].numpy(), mu.numpy(), sd.numpy()],1))
    r=np.concatenate(res); y,mu,sd=r[:,0],r[:,1],r[:,2]
    yc=np.minimum(y,0.1)
    bad=y>=0.07
    print(f"{meth} | {len(y)} | {yc.mean():.4f} | {mu.mean():.4f} | {(yc-mu).mean():+.4f} | {bad.mean():.3f} | {np.mean(mu[bad]+2*sd[bad]<0.07):.2f}")
