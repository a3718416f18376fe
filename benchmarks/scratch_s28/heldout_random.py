"""Session 28: the old and the new default dynamics models on fresh random source-world sequences (the default
data generator with another seed: the data neither model was trained on), labels by skill.

    PYTHONPATH=. python benchmarks/scratch_s28/heldout_random.py OLD_MODEL_DIR NEW_MODEL_DIR|default [--batches 2]
"""

import sys

import numpy as np


def main() -> None:
    from dynamics import DataConfig, generate_transitions
    from task import state_distance

    sys.path.insert(0, "benchmarks/scratch_s28")
    from focus_pours import load_model

    n = int(sys.argv[sys.argv.index("--batches") + 1]) if "--batches" in sys.argv else 2
    ds = generate_transitions(DataConfig(seed=1000), "source", n_batches=n, progress=False)
    full_pour = (ds.a[:, 0] == 1) & (ds.s[:, 3] > 0.97) & (ds.a[:, 1] > 0.9)
    for spec in [a for a in sys.argv[1:3]]:
        pred = load_model(spec).predict_np(ds.s.astype(np.float64), ds.a.astype(np.float64))
        lab = state_distance(pred, ds.s_next)
        rows = {"moves": ds.a[:, 0] == 0, "pours": ds.a[:, 0] == 1, "full-cup pours, tilt > 0.9": full_pour}
        print(f"== {spec}: {len(ds)} transitions")
        for k, m in rows.items():
            L = lab[m]
            print(f"  {k:28s} n {m.sum():4d} label mean {L.mean():.4f} median {np.median(L):.4f} "
                  f"mean+2std {L.mean() + 2 * L.std():.3f} over d_max {(L > 0.07).mean():.3f}")


if __name__ == "__main__":
    main()
