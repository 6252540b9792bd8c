import numpy as np

from sparse_brdf.coords import (
    MERL_SHAPE,
    angles_to_bins,
    angles_to_dirs,
    bin_angles,
    cos_io,
    dirs_to_angles,
    dirs_to_bins,
    geometric_valid,
    grid_angles,
)


def _random_pairs(n, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_angles_dirs_round_trip():
    rng = np.random.default_rng(1)
    th = rng.uniform(0, np.pi / 2, 1000)
    td = rng.uniform(0, np.pi / 2, 1000)
    pd = rng.uniform(-np.pi + 1e-3, np.pi - 1e-3, 1000)
    wi, wo = angles_to_dirs(th, td, pd)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=-1), 1, atol=1e-12)
    th2, td2, pd2 = dirs_to_angles(wi, wo)
    np.testing.assert_allclose(th2, th, atol=1e-7)
    np.testing.assert_allclose(td2, td, atol=1e-7)
    keep = (th > 1e-3) & (td > 1e-3)  # phi_d is undefined at the poles
    np.testing.assert_allclose(pd2[keep], pd[keep], atol=1e-6)


def test_dirs_angles_round_trip_with_phi_h():
    wi, wo = _random_pairs(500)
    wi2, wo2 = angles_to_dirs(*dirs_to_angles(wi, wo))
    # angles_to_dirs uses phi_h = 0: the pair is rotated about z, angles between kept
    np.testing.assert_allclose(np.sum(wi2 * wo2, -1), np.sum(wi * wo, -1), atol=1e-9)
    np.testing.assert_allclose(wi2[:, 2], wi[:, 2], atol=1e-9)
    np.testing.assert_allclose(wo2[:, 2], wo[:, 2], atol=1e-9)


def test_reciprocity_same_bin():
    wi, wo = _random_pairs(5000, seed=3)
    a = dirs_to_bins(wi, wo)
    b = dirs_to_bins(wo, wi)
    # phi_d differs by exactly pi; floor at a bin edge may differ on a measure-zero set
    agree = np.all(np.stack(a) == np.stack(b), axis=0)
    assert agree.mean() > 0.999


def test_known_directions():
    n = np.array([0.0, 0.0, 1.0])
    # normal incidence and reflection: theta_h = theta_d = 0 -> bin (0, 0, 0)
    assert [int(x) for x in dirs_to_bins(n, n)] == [0, 0, 0]
    # wi = wo at 45 degrees: theta_h = 45 deg -> i_h = floor(sqrt(0.5) * 90) = 63
    w = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.5)])
    assert [int(x) for x in dirs_to_bins(w, w)] == [63, 0, 0]
    # mirror pair at 60 degrees from the normal: h = n, theta_d = 60 deg -> i_d = 60
    wi = np.array([np.sin(np.pi / 3), 0, np.cos(np.pi / 3)])
    wo = np.array([-wi[0], 0, wi[2]])
    th, td, pd = dirs_to_angles(wi, wo)
    assert abs(th) < 1e-9 and abs(td - np.pi / 3) < 1e-9
    assert [int(x) for x in dirs_to_bins(wi, wo)] == [0, 60, 0]


def test_phi_folding_and_clamping():
    i = angles_to_bins(np.array([2.0]), np.array([1.6]), np.array([-np.pi / 2]))
    assert [int(x[0]) for x in i] == [89, 89, 90]
    assert [int(x) for x in angles_to_bins(-0.1, 0.0, np.pi)] == [0, 0, 179]


def test_bin_angles_map_to_own_bin():
    th, td, pd = grid_angles(MERL_SHAPE)
    eps = 1e-9
    i = angles_to_bins(th + eps, td + eps, pd + eps)
    for k, ax in enumerate(i):
        assert np.array_equal(ax, np.indices(MERL_SHAPE)[k])
    assert bin_angles()[0][1] == (1 / 90) ** 2 * np.pi / 2


def test_validity_and_cosines():
    valid = geometric_valid(MERL_SHAPE)
    ci, co = cos_io(*grid_angles(MERL_SHAPE))
    assert valid[0].all()  # theta_h = 0: both directions at theta_d from the normal
    assert not valid[89, 89, 0]  # grazing half vector with wide opening, phi_d = 0
    assert np.array_equal(valid, (ci > 0) & (co > 0))
    wi, wo = angles_to_dirs(*grid_angles(MERL_SHAPE))
    np.testing.assert_allclose(wi[..., 2], ci, atol=1e-12)
    np.testing.assert_allclose(wo[..., 2], co, atol=1e-12)
