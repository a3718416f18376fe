"""Session 21 probe (not a benchmark): single pours from where clean pours happen, per viscosity.

Every trajectory is move(target_x + dx, y) then pour(theta, hold) from one start, with dx in [0.04, 0.14],
y in [0.13, 0.22] (session 20: the only place the shipped data's pours are clean), theta in [0.9, 2.2] and hold
in [0, 1] drawn with one seed, so every viscosity executes the same pours. Each pour runs in two environment
slots (the water's initial particle sampling differs), which shows how reproducible the spill verdict is.
Over the pours that moved water (v_ctrl fell by > 0.02): share clean (spill < 0.02), share that would meet a
goal band anywhere (clean and v_tgt in [0.25, 0.85]), and how often the two slots disagree on "clean".

    PYTHONPATH=. python benchmarks/scratch_s21/viscosity_pours.py --out X.json --viscosity 0 3 10 [--n 32]
"""
from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--viscosity", type=float, nargs="+", default=[0.0, 3.0, 10.0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--world", default="source")
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    from sim.execute import PouringExecutor
    from sim.world import WorldConfig

    rng = np.random.default_rng(2021)
    n = args.n
    base = WorldConfig.load()
    tx = base.target_cup.x
    acts = [np.array([[0, tx + rng.uniform(0.04, 0.14), rng.uniform(0.13, 0.22)],
                      [1, rng.uniform(0.9, 2.2), rng.uniform(0.0, 1.0)]]) for _ in range(n)]
    start = np.array([0.43, 0.17, 0.0])
    out = {"n": n, "rows": []}
    for mu in args.viscosity:
        w = WorldConfig.load(sim={**base.sim, "viscosity": mu})
        ex = PouringExecutor(w)
        t0 = time.perf_counter()
        res = ex.run(args.world, np.tile(start, (2 * n, 1)), acts + acts, slots=list(range(2 * n)))
        ex.close()
        fin = np.array([r.states[-1] for r in res])  # (2n, 5)
        before = np.array([r.states[-2] for r in res])
        moved = before[:, 3] - fin[:, 3] > 0.02
        spill = 1 - fin[:, 3] - fin[:, 4]
        clean = spill < 0.02
        band = clean & (fin[:, 4] > 0.25) & (fin[:, 4] < 0.85)
        m2 = moved[:n] & moved[n:]
        row = {"viscosity": mu, "seconds": time.perf_counter() - t0, "pours_moved": int(moved.sum()),
               "clean_share": float(clean[moved].mean()), "goal_band_share": float(band[moved].mean()),
               "median_spill": float(np.median(spill[moved])),
               "slot_disagree_clean": float(np.mean(clean[:n][m2] != clean[n:][m2])),
               "slot_target_diff": float(np.mean(abs(fin[:n, 4] - fin[n:, 4])[m2])),
               "slot_spill_diff": float(np.mean(abs(spill[:n] - spill[n:])[m2])),
               "per_pour": [[float(x) for x in (*acts[i][0, 1:], *acts[i][1, 1:], fin[i, 4], spill[i],
                                                fin[n + i, 4], spill[n + i])] for i in range(n)]}
        out["rows"].append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "per_pour"}), flush=True)
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
