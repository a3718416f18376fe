"""The pour GP's prediction far from its data (mean, std, mean + 2 std in label units), its z-scored
outputscale, label std and share of labels at the cap, per method and round band:
PYTHONPATH=. python benchmarks/scratch_s37/pour_gp_far_prior.py RUN_DIR OUT.json"""
import sys
import numpy as np, json, math
import mde as M
RUN = sys.argv[1]
rows=[]
for it in range(1,21):
    for meth in ("active_balanced","active_cautious","active_mean","random_actions","random_plan"):
        for s in range(4):
            m=M.load(f"{RUN}/seed{s}/{meth}/mde_iter{it:03d}.pt")._children.get(1.0)
            if m is None: continue
            g=m._fitted.mean_model; cm=g.covar_module
            os_=float(cm.outputscale); noise=float(g.likelihood.noise.detach().ravel()[0]); c=float(g.mean_module.constant)
            mu=m.label_mean+c*m.label_std; sd=math.sqrt(os_+noise)*m.label_std
            rows.append(dict(it=it,method=meth,seed=s,mu_far=mu,sd_far=sd,ucb_far=mu+2*sd,os=os_,noise=noise,label_std=m.label_std,ymax_share=float((m.train_y>=0.0999).double().mean())))
json.dump(rows,open(sys.argv[2],'w'))
from collections import defaultdict
agg=defaultdict(list)
for r in rows: agg[(r['method'],'01-05' if r['it']<=5 else '06-10' if r['it']<=10 else '11-20')].append(r)
print("method band | far from data: mu, sd, mu+2sd, share of runs with mu+2sd<0.07 | z outputscale | label std | share of pour labels at the cap")
for k in sorted(agg):
    v=agg[k]; f=lambda key: np.mean([r[key] for r in v])
    print(k, f"{f('mu_far'):.3f} {f('sd_far'):.3f} {f('ucb_far'):.3f} {np.mean([r['ucb_far']<0.07 for r in v]):.2f} | {f('os'):.2f} | {f('label_std'):.3f} | {f('ymax_share'):.3f}")
