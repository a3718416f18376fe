"""Where the pour GP's mean at the good partial first pours of the s31 sets comes from: contributions by group of
training pour, and the labels of the 5 training pours most correlated (kernel) with each of them, per method:
PYTHONPATH=. python benchmarks/scratch_s37/partial_pour_neighbours.py RUN_DIR (every mde_iterNNN.pt kept)."""
import numpy as np, torch, sys
from pathlib import Path
from benchmarks.admission import labelled_set
import mde as M
data = labelled_set([Path(f"benchmarks/ceiling_sets/s31_stuck_seed{i}.npz") for i in range(3)], [])
m = data["partial"] & data["good"]
Xq = data["X"][m]
RUN = sys.argv[1]
for it in (4,):
  for meth in ("active_balanced","active_mean","random_plan"):
    for s in range(4):
        mde=M.load(f"{RUN}/seed{s}/{meth}/mde_iter{it:03d}.pt")._children[1.0]
        gp=mde._fitted.mean_model
        X=mde.train_X; y=mde.train_y
        muz,sz=mde.label_mean,mde.label_std
        yz=(y-muz)/sz
        c=float(gp.mean_module.constant)
        K=gp.covar_module(X).to_dense().detach()
        noise=float(gp.likelihood.noise.reshape(-1)[0])
        alpha=torch.linalg.solve(K+noise*torch.eye(len(X),dtype=K.dtype),(yz-c).reshape(-1,1)).reshape(-1)
        ks=gp.covar_module(Xq,X).to_dense().detach()  # q x n
        contrib=ks*alpha  # q x n, z units
        mu=(c+contrib.sum(1))*sz+muz
        pred=mde.predict(Xq)[0]
        # group training points
        full=(X[:,3]>0.5)
        high=(y>=0.07)
        groups={"full cup, label<0.07":full&~high,"full cup, label>=0.07":full&high,"part-empty cup, label<0.07":~full&~high,"part-empty, label>=0.07":~full&high}
        parts={k:float((contrib[:,g].sum(1)*sz).mean()) for k,g in groups.items()}
        print(it,meth,s,f"n={len(X)} prior {c*sz+muz:+.3f} mu {float(mu.mean()):.3f} (predict {float(pred.mean()):.3f}) |", " ".join(f"{k}: n={int(g.sum())} {parts[k]:+.3f}" for k,g in groups.items()))
print("--- top-5 most correlated training pours (kernel) per query: mean label, mean k, share of labels >= 0.07; all-data label mean")
for it in (4, 10):
  for meth in ("active_balanced","active_mean","random_plan"):
    out=[]
    for s in range(4):
        mde=M.load(f"{RUN}/seed{s}/{meth}/mde_iter{it:03d}.pt")._children[1.0]
        gp=mde._fitted.mean_model; X=mde.train_X; y=mde.train_y
        os_=float(gp.covar_module.outputscale)
        ks=(gp.covar_module(Xq,X).to_dense().detach()/os_)
        top=ks.topk(5,dim=1)
        yl=y[top.indices]
        out.append((float(yl.mean()), float(top.values.mean()), float((yl>=0.07).double().mean()), float(y.mean()), float(np.median(y.numpy()))))
    o=np.array(out)
    print(it, meth, "top5 label %.3f  corr %.2f  share>=0.07 %.2f | data mean %.3f median %.3f"%tuple(o.mean(0)), "| per seed top5 label", np.round(o[:,0],3), "corr", np.round(o[:,1],2))
