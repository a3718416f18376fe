"""Save / load round trip of the MDE (atomic write, identical predictions)."""

from __future__ import annotations

import pytest
import torch

import mde
from mde import GPMDE

T1 = {"num_threads": 1, "max_iters": 2}  # see tests/test_mde_model.py


def _data(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, 3, generator=g, dtype=torch.float64)
    y = 0.4 + torch.sin(3 * X[:, 0]) * 0.2 + (0.02 + 0.2 * X[:, 1]) * torch.randn(n, generator=g, dtype=torch.float64)
    return X, y.clamp_min(0.0)


@pytest.mark.parametrize(
    "config",
    [
        {},
        {"heteroscedastic": False},
        {"input_scaling": "normalize", "nu": 1.5},
        {"max_fit_points": 40},
        {"predict_dtype": "float64"},
        {"lengthscale_max": 2.0, "max_fit_points": 40},  # the bounds come back with the state
        {"latent_std_min": 5.0, "max_fit_points": 40},  # an outputscale bound (binding here) too
    ],
)
def test_round_trip_predicts_identically(tmp_path, config):
    torch.manual_seed(0)
    X, y = _data(70)
    m = GPMDE(**T1, **config).fit(X, y)
    path = m.save(tmp_path / "sub" / "mde.pt")
    loaded = GPMDE.load(path)
    assert loaded.config == m.config and loaded.n_train == 70 and loaded.n_features == 3
    assert loaded.fit_info == m.fit_info
    assert (loaded.noise_model is None) == (m.noise_model is None)
    Xq = torch.cat([X[:20], torch.rand(30, 3, dtype=torch.float64) * 3 - 1])
    for a, b in zip(m.predict(Xq), loaded.predict(Xq)):
        assert torch.equal(a, b)
    for noise in (False, True):
        pa = m.model.posterior(Xq.reshape(5, 10, 3), observation_noise=noise)
        pb = loaded.model.posterior(Xq.reshape(5, 10, 3), observation_noise=noise)
        torch.testing.assert_close(pa.mean, pb.mean, rtol=0, atol=0)
        torch.testing.assert_close(pa.variance, pb.variance, rtol=0, atol=0)
    assert [p.name for p in tmp_path.joinpath("sub").iterdir()] == ["mde.pt"]  # no temp files left


def test_round_trip_of_unfitted_model(tmp_path):
    m = GPMDE(prior_std=0.3).fit(torch.empty(0, 4, dtype=torch.float64), torch.empty(0))
    loaded = GPMDE.load(m.save(tmp_path / "prior.pt"))
    assert not loaded.is_fitted and loaded.n_features == 4 and loaded.config.prior_std == 0.3
    mean, std = loaded.predict(torch.rand(3, 4, dtype=torch.float64))
    assert torch.equal(mean, torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(std, torch.full((3,), 0.3, dtype=torch.float64))


def test_failed_save_leaves_previous_file_intact(tmp_path, monkeypatch):
    X, y = _data(30)
    m = GPMDE(heteroscedastic=False, **T1).fit(X, y)
    path = m.save(tmp_path / "mde.pt")
    before = path.read_bytes()

    def broken_save(obj, fh, *args, **kwargs):
        fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        GPMDE(heteroscedastic=False, **T1).fit(X[:10], y[:10]).save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["mde.pt"]


def test_load_rejects_other_files(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"X": torch.zeros(2, 2)}, path)
    with pytest.raises(ValueError, match="not a saved"):
        GPMDE.load(path)


def test_load_names_the_format_versions(tmp_path):
    """A saved MDE of another format version is refused, naming both versions."""
    path = GPMDE(**T1).save(tmp_path / "one.pt")
    payload = torch.load(path, weights_only=True)
    torch.save({**payload, "version": 0}, path)
    with pytest.raises(ValueError, match="has format version 0, this code reads version 1; fit the MDE again"):
        mde.load(path)
    torch.save({"format": "mde.GroupedMDE", "version": 1}, path)
    with pytest.raises(ValueError, match="has format version 1, this code reads version 2; fit the MDE again"):
        mde.load(path)
