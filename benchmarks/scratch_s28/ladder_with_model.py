"""Session 28 probe: the ladder (``python -m active.ladder``) with a dynamics ensemble from a folder of
``member*.pt`` checkpoints (``focus_pours.py train``) in place of the config's cached model.

    PYTHONPATH=. python benchmarks/scratch_s28/ladder_with_model.py MODEL_DIR --out D --rungs ... -- overrides
"""

import sys
from pathlib import Path


def main() -> None:
    model_dir = Path(sys.argv[1])
    import dynamics
    from dynamics.ensemble import DynamicsEnsemble
    from dynamics.model import LearnedDynamics

    ens = DynamicsEnsemble([LearnedDynamics.load(p) for p in sorted(model_dir.glob("member*.pt"))],
                           info={"model_hash": f"probe:{model_dir}"})
    import dynamics.train as train_mod

    def load_or_train(*args, **kwargs):
        return ens

    train_mod.load_or_train = load_or_train
    dynamics.__dict__["load_or_train"] = load_or_train
    from active.ladder import main as ladder_main

    ladder_main(sys.argv[2:])


if __name__ == "__main__":
    main()
