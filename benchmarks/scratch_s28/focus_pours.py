"""Session 28 probe: does source-world data focused on the pours plans make (a full cup moved next to the
target cup, then tilted onto the steep part of its outcome curve) make the dynamics model more accurate there?

    PYTHONPATH=. python benchmarks/scratch_s28/focus_pours.py gen  OUT.pt --batches 16 [--seed 1]
    PYTHONPATH=. python benchmarks/scratch_s28/focus_pours.py train OUT_DIR FOCUS.pt [FOCUS2.pt ...]
    PYTHONPATH=. python benchmarks/scratch_s28/focus_pours.py eval OUT.json MODEL_DIR|default ... --data HELDOUT.pt
    PYTHONPATH=. python benchmarks/scratch_s28/focus_pours.py count DATASET.pt

count: full-cup pours at tilt 1.0-1.5 from x 0.29-0.37 m, y < 0.22 m in a dataset (the old default data: 59 of 5,976).

gen: trajectories in the source world: start in the problems' start region, move to (x, y) on the lattice in
the focus box, pour (theta, hold), and with probability 0.5 a second, steeper pour. train: the default
ensemble's three members (seeds 0, 1, 2) on the shipped dataset plus the focus data. eval: each model's
one-step errors on held-out focus data (first pours from a full cup, by tilt), as the MDE label would see
them (d with weights 1) and in the target cup's fraction.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

FOCUS = {"x": (0.28, 0.35), "y": (0.10, 0.30), "theta": (0.9, 1.6), "hold": (0.0, 1.0)}


def gen(out: Path, batches: int, seed: int, batch_size: int = 32) -> None:
    from active.run import compose_config
    from dynamics.data import Transitions, _collect
    from sim.execute import PouringExecutor
    from sim.skills import move, pour
    from sim.world import WorldConfig

    cfg = compose_config([])
    world = WorldConfig.from_mapping(cfg["world"])
    pr = world.problems
    ex = PouringExecutor(world)
    parts = []
    try:
        for b in range(batches):
            rng = np.random.default_rng([seed, b, 28])
            starts, seqs = [], []
            for _ in range(batch_size):
                start = np.round([rng.uniform(*pr["start_x"]), rng.uniform(*pr["start_y"])], 2)
                x, y = np.round([rng.uniform(*FOCUS["x"]), rng.uniform(*FOCUS["y"])], 2)
                th = rng.uniform(*FOCUS["theta"])
                seq = [move(x, y), pour(th, rng.uniform(*FOCUS["hold"]))]
                if rng.random() < 0.5:
                    seq.append(pour(min(th + rng.uniform(0.0, 0.4), world.skills["pour"]["theta"][1]),
                                    rng.uniform(*FOCUS["hold"])))
                starts.append(start)
                seqs.append(seq)
            res = ex.run("source", np.array(starts), seqs)
            part, c = _collect(res, np.zeros((batch_size, 3)), traj_offset=10_000_000 + b * batch_size)
            parts.append(part)
            print(f"batch {b}: {len(part)} transitions, {c['categories']}", flush=True)
    finally:
        ex.close()
    ds = Transitions.concat(parts)
    ds.meta = {"focus": FOCUS, "seed": seed, "batches": batches}
    ds.save(out)
    print(f"wrote {out}: {len(ds)} transitions")


def train(out_dir: Path, focus_files: list[Path], members: int = 3) -> None:
    from active.run import compose_config
    from dynamics.config import DynamicsConfig, ensemble_member
    from dynamics.data import Transitions
    from dynamics.train import fit, load_or_generate_dataset
    from sim.world import WorldConfig

    cfg = compose_config([])
    c = DynamicsConfig.from_dict(dict(cfg["dynamics"]))
    base = load_or_generate_dataset(c, world_cfg=cfg["world"], progress=False)
    ds = Transitions.concat([base] + [Transitions.load(f) for f in focus_files])
    print(f"training on {len(base)} + {len(ds) - len(base)} transitions")
    out_dir.mkdir(parents=True, exist_ok=True)
    world = WorldConfig.from_mapping(cfg["world"])
    for k in range(members):
        m = ensemble_member(c, k)
        model = fit(ds, m.model, m.train, world_cfg=world)
        model.save(out_dir / f"member{k}.pt")
        print(f"member {k}: {model.info['training']['epochs_run']} epochs, val {model.info['training']['best_val_loss']:.4f}, "
              f"{model.info['training']['wall_seconds']:.0f} s", flush=True)


def load_model(spec: str):
    import dynamics
    from active.run import compose_config
    from dynamics.ensemble import DynamicsEnsemble
    from dynamics.model import LearnedDynamics

    if spec == "default":
        cfg = compose_config([])
        return dynamics.load_or_train(cfg["dynamics"], world_cfg=cfg["world"], progress=False)
    return DynamicsEnsemble([LearnedDynamics.load(p) for p in sorted(Path(spec).glob("member*.pt"))])


def evaluate(out: Path, specs: list[str], data: Path) -> None:
    from dynamics.data import Transitions
    from task import state_distance

    ds = Transitions.load(data)
    pour = (ds.a[:, 0] == 1) & (ds.s[:, 3] > 0.97)
    rows = {}
    for spec in specs:
        pred = load_model(spec).predict_np(ds.s.astype(np.float64), ds.a.astype(np.float64))
        lab = state_distance(pred, ds.s_next)
        err_t = np.abs(pred[:, 4] - ds.s_next[:, 4])
        r = {}
        for lo, hi in ((0.9, 1.15), (1.15, 1.25), (1.25, 1.35), (1.35, 1.6), (0.9, 1.6)):
            m = pour & (ds.a[:, 1] >= lo) & (ds.a[:, 1] < hi)
            L = lab[m]
            r[f"{lo}-{hi}"] = {"n": int(m.sum()), "label_median": float(np.median(L)), "label_mean_2std": float(L.mean() + 2 * L.std()),
                               "over_dmax": float((L > 0.07).mean()), "target_abs_err_median": float(np.median(err_t[m])),
                               "target_bias": float(np.mean(pred[m, 4] - ds.s_next[m, 4]))}
        second = (ds.a[:, 0] == 1) & (ds.s[:, 3] <= 0.97) & (ds.s[:, 3] > 0.05)
        r["second_pours"] = {"n": int(second.sum()), "label_median": float(np.median(lab[second])),
                             "label_mean_2std": float(lab[second].mean() + 2 * lab[second].std())}
        mv = ds.a[:, 0] == 0
        r["moves"] = {"n": int(mv.sum()), "label_median": float(np.median(lab[mv])), "label_mean_2std": float(lab[mv].mean() + 2 * lab[mv].std())}
        rows[spec] = r
        print(f"== {spec}")
        for k, v in r.items():
            print(f"  {k:12s} " + " ".join(f"{kk} {vv:.3f}" if isinstance(vv, float) else f"{kk} {vv}" for kk, vv in v.items()))
    out.write_text(json.dumps({"data": str(data), "models": rows}, indent=1))


def count(path: Path) -> None:
    from dynamics.data import Transitions

    ds = Transitions.load(path)
    s, a = ds.s, ds.a
    m = (a[:, 0] == 1) & (s[:, 3] > 0.97) & (a[:, 1] >= 1.0) & (a[:, 1] <= 1.5) & (s[:, 0] >= 0.29) & (s[:, 0] <= 0.37) \
        & (s[:, 1] < 0.22)
    print(f"{m.sum()} of {len(ds)} transitions: full-cup pours at tilt 1.0-1.5 from x 0.29-0.37 m, y < 0.22 m")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("gen")
    g.add_argument("out", type=Path)
    g.add_argument("--batches", type=int, default=16)
    g.add_argument("--seed", type=int, default=0)
    t = sub.add_parser("train")
    t.add_argument("out_dir", type=Path)
    t.add_argument("focus", type=Path, nargs="+")
    e = sub.add_parser("eval")
    e.add_argument("out", type=Path)
    e.add_argument("models", nargs="+")
    e.add_argument("--data", type=Path, required=True)
    sub.add_parser("count").add_argument("dataset", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "gen":
        gen(a.out, a.batches, a.seed)
    elif a.cmd == "count":
        count(a.dataset)
    elif a.cmd == "train":
        train(a.out_dir, a.focus)
    else:
        evaluate(a.out, a.models, a.data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
