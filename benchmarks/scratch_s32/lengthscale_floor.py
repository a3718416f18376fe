"""Session 32 probe: the ladder's ceiling rung with a floor on every GP lengthscale of the MDE, in standard deviations
of its input over the training data (a constant input counts 1), against the collapse of the move GP's lengthscale on
the nearly constant volume fractions seen in small-data fits. A monkeypatch of ``mde.gp._kernel``, not an option.

    PYTHONPATH=. python benchmarks/scratch_s32/lengthscale_floor.py LMIN -- <python -m active.ladder arguments>
"""

import sys

import torch
from gpytorch.constraints import GreaterThan

import mde.gp as gp

LMIN = float(sys.argv[1])
_orig = gp._kernel


def _floored(nu, d, X_t, lengthscale_max=None, priors="none"):
    k = _orig(nu, d, X_t, lengthscale_max, priors)
    raw_std = X_t.std(dim=0) if X_t.shape[0] > 1 else torch.ones(d, dtype=gp.DTYPE)
    std = torch.where(raw_std > 1e-6, raw_std, torch.ones_like(raw_std)).to(gp.DTYPE)
    lo = (LMIN * std).reshape(1, d)
    base = k.base_kernel
    start = base.lengthscale.detach().clone()
    if lengthscale_max is not None:
        raise SystemExit("this probe does not combine with mde.lengthscale_max")
    base.register_constraint("raw_lengthscale", GreaterThan(lo))
    base.lengthscale = torch.maximum(start, 1.5 * lo)
    return k


gp._kernel = _floored

if __name__ == "__main__":
    from active.ladder import main

    args = sys.argv[2:]
    main(args[1:] if args and args[0] == "--" else args)
