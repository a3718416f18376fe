"""Dynamics network: valid outputs for any input, API agreement, input errors, checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dynamics import DynamicsError, LearnedDynamics, ModelConfig


def random_model(seed: int = 0, scale: float = 3.0) -> LearnedDynamics:
    """Network with large random weights and statistics, so that outputs are far from the init."""
    torch.manual_seed(seed)
    m = LearnedDynamics(ModelConfig(hidden=(32, 32)))
    with torch.no_grad():
        for p in m.parameters():
            p.copy_(torch.randn_like(p) * scale)
        for net in m.nets:
            net.in_mean.copy_(torch.randn_like(net.in_mean) * 0.1)
            net.in_std.copy_(torch.rand_like(net.in_std) + 0.05)
            net.pose_scale.copy_(torch.rand(3) * 0.1 + 0.001)
    m.invalidate_cache()
    return m


def random_inputs(n: int, seed: int = 0, wild: bool = False) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = (-2.0, 3.0) if wild else (0.0, 1.0)
    s = np.column_stack(
        [
            rng.uniform(0, 0.6, n),
            rng.uniform(0, 0.5, n),
            rng.uniform(-1, 2.5, n),
            rng.uniform(lo, hi, n),
            rng.uniform(lo, hi, n),
        ]
    )
    a = np.column_stack([rng.integers(0, 2, n), rng.uniform(-1, 3, n), rng.uniform(-1, 2, n)])
    return s, a


@pytest.mark.parametrize("wild", [False, True])
def test_outputs_are_valid_states(wild):
    m = random_model()
    s, a = random_inputs(4000, wild=wild)
    out = m.predict(torch.tensor(s), torch.tensor(a))
    assert out.dtype == torch.float32 and out.shape == (4000, 5)
    assert torch.isfinite(out).all()
    v = out[:, 3:5]
    assert (v >= 0).all() and (v <= 1).all() and (v.sum(1) <= 1 + 1e-6).all()
    if not wild:  # water only leaves the controlled cup: v_ctrl never grows, v_tgt and spill never shrink
        sv = torch.tensor(s[:, 3:5], dtype=torch.float32)
        valid = sv.sum(1) <= 1
        assert (v[valid, 0] <= sv[valid, 0] + 1e-6).all() and (v[valid, 1] >= sv[valid, 1] - 1e-6).all()
        spill_in, spill_out = 1 - sv[valid].sum(1), 1 - v[valid].sum(1)
        assert (spill_out >= spill_in - 1e-5).all()


def test_nominal_structure_at_initialisation():
    """A fresh net predicts 'move reaches its target, pour leaves the pose, little water moves'."""
    torch.manual_seed(0)
    m = LearnedDynamics(ModelConfig(hidden=(16,)))
    s = torch.tensor([[0.4, 0.2, 0.0, 1.0, 0.0], [0.4, 0.2, 0.0, 1.0, 0.0]])
    a = torch.tensor([[0.0, 0.3, 0.15], [1.0, 1.0, 0.5]])
    out = m.predict(s, a)
    # measured (torch seed 0): the move lands within 0.0154 of its target (0.0182 at most over seeds 0-5), the pour
    # within 0.0109 of the current pose; 0.02 is a fifth of the 0.1 m move, so a net that ignores the target fails
    assert (out[0, :3] - torch.tensor([0.3, 0.15, 0.0])).abs().max() < 0.02
    assert (out[1, :3] - s[1, :3]).abs().max() < 0.02
    assert out[0, 3] > 0.5 and out[1, 3] > 0.5


def test_batched_numpy_and_single_paths_agree():
    m = random_model(scale=0.5)
    s, a = random_inputs(257, seed=1)
    t = m.predict(torch.tensor(s), torch.tensor(a)).double().numpy()
    n = m.predict_np(s, a)
    assert np.abs(t - n).max() < 1e-5
    for i in (0, 1, 100):
        assert np.abs(m.predict_one(s[i], a[i]) - n[i]).max() < 1e-9
        assert np.abs(m.predict(torch.tensor(s[i : i + 1]), torch.tensor(a[i : i + 1]))[0].numpy() - n[i]).max() < 1e-5
    only_pour = a[a[:, 0] == 1]
    assert np.allclose(
        m.predict_np(s[: len(only_pour)], only_pour),
        m.predict(torch.tensor(s[: len(only_pour)]), torch.tensor(only_pour)).numpy(),
        atol=1e-5,
    )


@pytest.mark.parametrize("activation", ["silu", "tanh", "relu"])
def test_in_place_activations_give_the_bits_of_the_plain_formulas(activation):
    """The numpy batch path applies its activations in place (no temporaries); the plan results depend on
    every bit of the model (a planner run is a chaotic function of it), so the arithmetic must stay the same."""
    from dynamics.model import _ACT_NP, _ACT_NP_INPLACE

    h = np.random.default_rng(0).normal(0.0, 4.0, (3, 40, 16))
    h[0, 0, :3] = (0.0, -800.0, 800.0)  # exp overflow and underflow
    ref = _ACT_NP[activation](h.copy())
    got = h.copy()
    _ACT_NP_INPLACE[activation](got)
    np.testing.assert_array_equal(got, ref)


def test_numpy_cache_follows_weight_changes(tmp_path):
    m = random_model(scale=0.5)
    s, a = random_inputs(8)
    before = m.predict_np(s, a)
    m.load_state_dict(random_model(seed=1, scale=0.5).state_dict())
    after = m.predict_np(s, a)
    assert not np.allclose(before, after)
    assert np.allclose(after, m.predict(torch.tensor(s), torch.tensor(a)).numpy(), atol=1e-5)


@pytest.mark.parametrize(
    "s_shape, a_shape, match",
    [
        ((4, 4), (4, 3), r"states must have shape \[n, 5\]"),
        ((4, 5), (4, 2), r"actions must have shape \[n, 3\]"),
        ((5,), (3,), r"states must have shape \[n, 5\]"),
        ((4, 5), (3, 3), r"4 states but 3 actions"),
    ],
)
def test_shape_errors(s_shape, a_shape, match):
    m = random_model()
    with pytest.raises(DynamicsError, match=match):
        m.predict(torch.zeros(s_shape), torch.zeros(a_shape))
    if len(s_shape) == 2:
        with pytest.raises(DynamicsError, match=match):
            m.predict_np(np.zeros(s_shape), np.zeros(a_shape))


def test_value_errors():
    m = random_model()
    s, a = random_inputs(3)
    bad = a.copy()
    bad[1, 0] = 2
    with pytest.raises(DynamicsError, match=r"action 1 has skill id 2; allowed 0 \(move\) or 1 \(pour\)"):
        m.predict(torch.tensor(s), torch.tensor(bad))
    with pytest.raises(DynamicsError, match=r"action 1 has skill id 2"):
        m.predict_np(s, bad)
    bad[1, 0] = 0.5
    with pytest.raises(DynamicsError, match="skill id 0.5"):
        m.predict(torch.tensor(s), torch.tensor(bad))
    s2 = s.copy()
    s2[2, 3] = np.nan
    with pytest.raises(DynamicsError, match="NaN or inf"):
        m.predict(torch.tensor(s2), torch.tensor(a))
    with pytest.raises(DynamicsError, match="NaN or inf"):
        m.predict_one(s2[2], a[2])
    with pytest.raises(DynamicsError, match=r"skill id 2; allowed 0 \(move\) or 1 \(pour\)"):
        m.predict_one(s[0], [2, 0.3, 0.2])
    with pytest.raises(DynamicsError, match=r"expected a state of 5 and an action of 3 numbers"):
        m.predict_one(s[0, :4], a[0])


def test_checkpoint_round_trip_is_identical(tmp_path):
    m = random_model(scale=0.5)
    m.info = {"model_hash": "abc", "note": "x"}
    path = m.save(tmp_path / "m.pt")
    m2 = LearnedDynamics.load(path, expected_hash="abc")
    s, a = random_inputs(100)
    st, at = torch.tensor(s), torch.tensor(a)
    assert torch.equal(m.predict(st, at), m2.predict(st, at))
    assert np.array_equal(m.predict_np(s, a), m2.predict_np(s, a))
    assert m2.info["note"] == "x" and m2.cfg == m.cfg


def test_checkpoint_errors(tmp_path):
    m = random_model()
    m.info = {"model_hash": "abc"}
    path = m.save(tmp_path / "m.pt")
    with pytest.raises(
        DynamicsError, match=r"trained with another config \(hash abc, expected xyz\).*python -m dynamics.train"
    ):
        LearnedDynamics.load(path, expected_hash="xyz")
    with pytest.raises(DynamicsError, match="does not exist; train it with `python -m dynamics.train`"):
        LearnedDynamics.load(tmp_path / "none.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(path.read_bytes()[:300])
    with pytest.raises(
        DynamicsError, match=r"corrupt.*delete .*corrupt.pt and retrain with `python -m dynamics.train`"
    ):
        LearnedDynamics.load(corrupt)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(DynamicsError, match="not a dynamics checkpoint"):
        LearnedDynamics.load(other)
    # same format, different architecture (e.g. a checkpoint from code with another layout)
    payload = torch.load(path, weights_only=True)
    payload["state_dict"]["nets.0.mlp.0.weight"] = torch.zeros(7, 7)
    torch.save(payload, other)
    with pytest.raises(DynamicsError, match="does not match this model code"):
        LearnedDynamics.load(other)


def test_satisfies_planner_protocol():
    interfaces = pytest.importorskip("planner.interfaces")
    m = random_model()
    assert isinstance(m, interfaces.DynamicsModel)


def test_pour_sweep_bounding_box():
    """The tilt's swept region: upright = the cup's outer box; the numpy twin agrees with torch."""
    from dynamics.model import DEFAULT_CUP, pour_sweep, pour_sweep_np

    w, h, wall = DEFAULT_CUP
    s = torch.tensor([[0.4, 0.2, 0.0, 1.0, 0.0], [0.3, 0.15, 0.0, 0.5, 0.2]], dtype=torch.float64)
    box = pour_sweep(s, torch.zeros(2, dtype=torch.float64), torch.tensor(DEFAULT_CUP))
    assert np.allclose(box[0], [0.4 - w / 2 - wall, 0.4 + w / 2 + wall, 0.2 - wall, 0.2 + h])
    tilt = pour_sweep(s, torch.tensor([np.pi / 2, 1.0], dtype=torch.float64), torch.tensor(DEFAULT_CUP))
    # a quarter turn about the lip (top-left outer corner): the far bottom corner reaches furthest right
    # at 45 degrees, and ends one cup width above the lip
    lip_x, lip_y = 0.4 - w / 2 - wall, 0.2 + h
    assert np.isclose(tilt[0, 1], lip_x + np.hypot(w + 2 * wall, h + wall)) and np.isclose(tilt[0, 2], 0.2 - wall)
    assert np.isclose(tilt[0, 3], lip_y + w + 2 * wall)
    assert np.allclose(pour_sweep_np(s.numpy(), np.array([np.pi / 2, 1.0]), DEFAULT_CUP), tilt.numpy())


def test_cup_geometry_travels_in_the_checkpoint(tmp_path):
    m = random_model(scale=0.5)
    m.set_cup_geometry(0.08, 0.1, 0.015)
    m2 = LearnedDynamics.load(m.save(tmp_path / "m.pt"))
    assert torch.allclose(m2.nets[1].cup_geom, torch.tensor([0.08, 0.1, 0.015]))
    s, a = random_inputs(50)
    assert np.allclose(m2.predict_np(s, a), m.predict(torch.tensor(s), torch.tensor(a)).numpy(), atol=1e-5)


def test_ensemble_numpy_path_is_the_members_mean_and_follows_weight_changes():
    """The ensemble's stacked-weight numpy path equals averaging the members' own numpy paths."""
    from dynamics import DynamicsEnsemble

    members = [random_model(seed=k, scale=0.5) for k in range(3)]
    ens = DynamicsEnsemble(members)
    s, a = random_inputs(65, seed=2)
    mean = sum(m.predict_np(s, a) for m in members) / 3
    np.testing.assert_allclose(ens.predict_np(s, a), mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ens.predict_np(s[3], a[3]), mean[3], rtol=0, atol=1e-12)  # one row in, one out
    pours = a[:, 0] == 1
    np.testing.assert_allclose(ens.predict_np(s[pours], a[pours]), mean[pours], rtol=0, atol=1e-12)
    with pytest.raises(DynamicsError, match=r"skill id 2"):
        ens.predict_np(s[:2], np.array([[2, 1, 1], [0, 1, 1]]))
    # a member's weights change: the stacked copy is rebuilt
    members[1].load_state_dict(random_model(seed=7, scale=0.5).state_dict())
    mean = sum(m.predict_np(s, a) for m in members) / 3
    np.testing.assert_allclose(ens.predict_np(s, a), mean, rtol=0, atol=1e-12)
    # new weights loaded through the ensemble itself reach its numpy path too
    ens.load_state_dict(DynamicsEnsemble([random_model(seed=k + 10, scale=0.5) for k in range(3)]).state_dict())
    mean = sum(m.predict_np(s, a) for m in members) / 3
    np.testing.assert_allclose(ens.predict_np(s, a), mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ens.predict_np(s, a), ens.predict(torch.tensor(s), torch.tensor(a)).numpy(), atol=1e-5)
    moves = a[:, 0] == 0
    np.testing.assert_allclose(ens.predict_np(s[moves], a[moves]), mean[moves], rtol=0, atol=1e-12)
    assert ens.predict_np(s[:0], a[:0]).shape == (0, 5)
    # members that cannot be stacked (another width) are averaged one by one
    odd = DynamicsEnsemble([members[0], LearnedDynamics(ModelConfig(hidden=(16,)))])
    np.testing.assert_allclose(
        odd.predict_np(s, a), (members[0].predict_np(s, a) + odd.members[1].predict_np(s, a)) / 2, rtol=0, atol=1e-12
    )
