"""Geometry of the scene: coordinates agree with the grid's moves; the kappa shading agrees with
the core advisor's decision rule."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, kl_divergence
from app.advice.models import AdviceTables
from app.domain.generate import generate_domain
from app.domain.grid import N_ACTIONS, GridDomain
from app.viewer import geometry as geo

seeds = st.integers(0, 2**32 - 1)


def random_theta(rng: np.random.Generator, n: int) -> np.ndarray:
    """Dirichlet rows, some of them uniform and some nearly one-hot, as real priors have."""
    theta = rng.dirichlet(np.full(N_ACTIONS, rng.choice([0.1, 1.0, 10.0])), size=n)
    theta[rng.random(n) < 0.2] = 0.25
    return theta


def test_cell_centres_row_zero_is_at_the_top(domain: GridDomain) -> None:
    rows, _ = domain.shape
    top, bottom = geo.cell_centres(domain, [(0, 0), (rows - 1, 0)])
    assert top[1] > bottom[1]
    assert top[1] == pytest.approx(rows - 0.5)
    assert bottom[0] == pytest.approx(0.5)


@given(seeds)
def test_action_vectors_follow_the_grid_moves(seed: int) -> None:
    """Moving by action a shifts a cell's centre by exactly ACTION_VECTORS[a]."""
    rng = np.random.default_rng(seed)
    d = generate_domain(int(rng.integers(5, 16)), int(rng.integers(5, 16)), seed=seed, braid=0.5)
    s = rng.integers(d.n_states, size=20)
    a = rng.integers(N_ACTIONS, size=20)
    moved = d.next_state[s, a] != s
    before = geo.cell_centres(d, d.cells[s[moved]])
    after = geo.cell_centres(d, d.cells[d.next_state[s[moved], a[moved]]])
    np.testing.assert_allclose(after[:, :2] - before[:, :2], geo.ACTION_VECTORS[a[moved]])


def test_z_rotations_turn_plus_x_into_each_action_vector() -> None:
    q = geo.z_rotations(geo.ACTION_ANGLES)
    for (w, _, _, z), v in zip(q, geo.ACTION_VECTORS, strict=True):
        # rotating (1, 0) by angle phi about z, with w = cos(phi/2), z = sin(phi/2)
        rotated = np.array([w * w - z * z, 2 * w * z])
        np.testing.assert_allclose(rotated, v, atol=1e-12)


def test_box_mesh_faces_point_outwards() -> None:
    v, f = geo.box_mesh()
    tri = v[f]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, tri.mean(axis=1)) > 0)
    assert len(np.unique(f)) == 8


def test_prior_arrows_one_per_cell_and_action(domain: GridDomain, theta: np.ndarray) -> None:
    positions, wxyzs, scales, opacities = geo.prior_arrows(domain, theta)
    n = domain.n_states * N_ACTIONS
    assert positions.shape == (n, 3) and wxyzs.shape == (n, 4) and scales.shape == (n, 3)
    # instance 4 s + a: at the centre of s, pointing along a, as long as theta_s(a) says
    s, a = 5, 2
    np.testing.assert_allclose(
        positions[4 * s + a, :2], geo.cell_centres(domain, [domain.cell(s)])[0, :2]
    )
    np.testing.assert_allclose(wxyzs[4 * s + a], geo.z_rotations(geo.ACTION_ANGLES)[a])
    np.testing.assert_allclose(scales[:, 0], geo.ARROW_REACH * theta.ravel())
    order = np.argsort(theta.ravel())
    assert np.all(np.diff(opacities[order]) >= 0)


def test_prior_arrows_refuse_a_theta_of_the_wrong_shape(domain: GridDomain) -> None:
    with pytest.raises(ValueError, match="theta must have shape"):
        geo.prior_arrows(domain, np.full((domain.n_states + 1, 4), 0.25))


@given(seeds, st.floats(0.0, 1.0))
def test_kl_to_expected_matches_the_core_kl(seed: int, p_normal: float) -> None:
    """The vectorised eq. (4) + (6) against kl_divergence one state at a time."""
    rng = np.random.default_rng(seed)
    theta = random_theta(rng, 30)
    fast = geo.kl_to_expected(theta, p_normal)
    slow = [kl_divergence(t, p_normal * t + (1 - p_normal) / 4) for t in theta]
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-12)


@given(seeds, st.floats(0.0, 1.4))
def test_advised_cells_at_half_match_a_fresh_advisor(seed: int, kappa: float) -> None:
    """With P(M1 | H) = 1/2 (empty H) the shading is exactly the advisor's start decisions."""
    rng = np.random.default_rng(seed)
    theta = random_theta(rng, 40)
    advisor = Advisor(AdviceTables.paper(theta), kappa=kappa)
    decisions = [advisor.decide(s) for s in range(len(theta))]
    mask = geo.advised_cells(theta, kappa, p_normal=0.5)
    clear = np.array([abs(d.kl - kappa) > 1e-9 for d in decisions])  # not on the threshold
    assert np.array_equal(mask[clear], np.array([d.advise for d in decisions])[clear])


@given(seeds, st.floats(0.0, 1.0), st.floats(0.0, 1.4))
def test_a_lost_explorer_gets_the_most_advice(seed: int, p_normal: float, kappa: float) -> None:
    """KL[theta || p theta + (1-p) u] falls as p grows, so p = 0 shades a superset."""
    theta = random_theta(np.random.default_rng(seed), 40)
    lost = geo.advised_cells(theta, kappa, 0.0)
    some = geo.advised_cells(theta, kappa, p_normal)
    assert np.all(lost[some])
    assert not geo.advised_cells(theta, max(kappa, 1e-9), 1.0).any()


def test_uniform_cells_are_never_shaded_and_one_hot_cells_are_until_log4() -> None:
    theta = np.array([[0.25] * 4, [1.0, 0.0, 0.0, 0.0]])
    kl = geo.kl_to_expected(theta, 0.0)
    assert kl[0] == pytest.approx(0.0)
    assert kl[1] == pytest.approx(np.log(4))
    assert geo.advised_cells(theta, 1.38, 0.0).tolist() == [False, True]
    assert geo.advised_cells(theta, 1.39, 0.0).tolist() == [False, False]


def test_kl_to_expected_refuses_p_normal_outside_0_1() -> None:
    with pytest.raises(ValueError, match="p_normal"):
        geo.kl_to_expected(np.full((2, 4), 0.25), 1.5)


@given(seeds)
def test_path_segments_match_a_path_by_path_loop(seed: int) -> None:
    """All paths in one pass against joining each path's consecutive distinct cells."""
    rng = np.random.default_rng(seed)
    d = generate_domain(9, 11, seed=seed % 1000, braid=0.4)
    paths = []
    for _ in range(int(rng.integers(0, 6))):
        s = int(rng.integers(d.n_states))
        path = [d.cell(s)]
        for a in rng.integers(0, 4, int(rng.integers(0, 30))):
            s = d.step(s, int(a))
            path.append(d.cell(s))
        paths.append(path)
    segments, owner, age = geo.path_segments(d, paths, z=0.1)
    expected, expected_owner, expected_age = [], [], []
    for k, path in enumerate(paths):
        for i in range(1, len(path)):
            if path[i] != path[i - 1]:
                expected.append(geo.cell_centres(d, [path[i - 1], path[i]], 0.1))
                expected_owner.append(k)
                expected_age.append(i / (len(path) - 1))
    assert segments.shape == (len(expected), 2, 3)
    if expected:
        np.testing.assert_allclose(segments, np.stack(expected))
    assert owner.tolist() == expected_owner
    np.testing.assert_allclose(age, expected_age)


@given(seeds, st.floats(0.0, 0.5))
def test_advice_arrows_point_along_each_likely_action(seed: int, min_p: float) -> None:
    rng = np.random.default_rng(seed)
    d = generate_domain(7, 9, seed=1)
    cells = d.cells[rng.integers(d.n_states, size=int(rng.integers(0, 8)))]
    probs = random_theta(rng, len(cells))
    points, row = geo.advice_arrows(d, cells, probs, reach=0.8, min_p=min_p, z=0.3)
    expected = [(k, a) for k in range(len(cells)) for a in range(4) if probs[k, a] >= min_p]
    assert row.tolist() == [k for k, _ in expected]
    for (start, end), (k, a) in zip(points, expected, strict=True):
        np.testing.assert_allclose(start, geo.cell_centres(d, [cells[k]], 0.3)[0])
        step = end[:2] - start[:2]
        np.testing.assert_allclose(step, 0.8 * probs[k, a] * geo.ACTION_VECTORS[a], atol=1e-12)


@given(
    st.integers(2, 600), st.integers(2, 600), st.floats(0.1, 2.8), st.floats(0.1, 10.0),
    st.floats(0.0, 2.0),
)  # fmt: skip
def test_fit_height_shows_the_whole_map_and_fills_the_view(
    rows: int, cols: int, fov: float, aspect: float, top: float
) -> None:
    """A pinhole camera at the fitted height sees every corner of the map at the height
    ``top`` (the nearest to it, so the largest on screen), and the map's longer side (for
    the view's shape) spans the view but for the margin."""
    margin = 1.04
    height = geo.fit_height(rows, cols, fov, aspect, top=top, margin=margin)
    corners = np.array([[x, y] for x in (-cols / 2, cols / 2) for y in (-rows / 2, rows / 2)])
    # normalised device coordinates of the corners: x across, y up, both in [-1, 1] if seen
    depth = height - top
    ndc = corners / (depth * np.tan(fov / 2) * np.array([aspect, 1.0]))
    assert np.abs(ndc).max() == pytest.approx(1 / margin)


def test_fit_height_refuses_a_view_that_is_not_one() -> None:
    for fov, aspect in [(0.0, 1.0), (np.pi, 1.0), (1.0, 0.0), (1.0, float("nan"))]:
        with pytest.raises(ValueError, match="fov must be in"):
            geo.fit_height(10, 10, fov, aspect)
