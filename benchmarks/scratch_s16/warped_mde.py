"""Scratch (session 16): the MDE fitted on warped labels w(d) = log(1 + d / c), read back in label units.

predict returns the mean and std of d = c (exp(z) - 1) for z ~ N(m, s^2) (moment matching), so the
precondition mu + beta sigma < d_max keeps its meaning: the predictive distribution's mean and std.
"""
import math

import torch

from mde import GroupedMDE


class WarpedGroupedMDE(GroupedMDE):
    def __init__(self, config=None, warp_offset: float = 0.02, **overrides):
        super().__init__(config, **overrides)
        self.warp_offset = float(warp_offset)

    def fit(self, X, y):
        y = torch.as_tensor(y, dtype=torch.float64)
        return super().fit(X, torch.log1p(y / self.warp_offset))

    def predict(self, X):
        m, s = super().predict(X)
        c, v = self.warp_offset, s.double() ** 2
        mean = c * (torch.exp(m.double() + v / 2) - 1)
        var = c * c * torch.expm1(v) * torch.exp(2 * m.double() + v)
        return mean.to(m.dtype), var.sqrt().to(s.dtype)
