"""Ray casting against exact walls: hand-computed cases and a brute-force dense-polyline
reference."""

import math

import numpy as np
import pytest

from bsslam.errors import ConfigError
from bsslam.sim.geometry import Arc, PolarCurve, Segment, WallSet, ray_cast, rounded_rectangle_walls
from bsslam.sim.worlds import WORLDS

PAPER_CURVE = PolarCurve((0.0, 0.0), 5.0, 0.5, 5.0, 0.0, 0.0, math.pi)


def brute_force_ray_cast(polylines, origin, angles, max_range):
    """Nearest crossing of each beam with the chords of dense polylines (independent of the
    exact solvers: plain segment–ray intersection over every chord)."""
    a = np.vstack([p[:-1] for p in polylines])
    b = np.vstack([p[1:] for p in polylines])
    u = np.column_stack([np.cos(angles), np.sin(angles)])[:, None, :]
    v = (b - a)[None, :, :]
    w = a[None, :, :] - np.asarray(origin, dtype=float)[None, None, :]
    den = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * v[..., 1] - w[..., 1] * v[..., 0]) / den
        s = (w[..., 0] * u[..., 1] - w[..., 1] * u[..., 0]) / den
    t = np.where((den != 0) & (t > 0) & (s >= 0) & (s <= 1), t, np.inf).min(axis=1)
    t[t > max_range] = np.inf
    return t


def test_beam_perpendicular_to_segment_hits_at_its_distance():
    walls = WallSet((Segment((3.0, -1.0), (3.0, 2.0)),))
    r = ray_cast(walls, np.array([0.5, 0.25]), np.array([0.0]), 10.0)
    assert r[0] == pytest.approx(2.5, abs=1e-12)


def test_oblique_beam_on_segment_matches_trigonometry():
    walls = WallSet((Segment((2.0, -5.0), (2.0, 5.0)),))
    angle = math.radians(30.0)
    r = ray_cast(walls, np.zeros(2), np.array([angle]), 10.0)
    assert r[0] == pytest.approx(2.0 / math.cos(angle), abs=1e-12)


def test_arc_seen_from_its_centre_gives_its_radius_and_misses_outside_its_span():
    arc = Arc((1.0, -2.0), 3.5, start_rad=0.2, span_rad=1.0)
    angles = np.linspace(0.0, 2 * math.pi, 720, endpoint=False)
    r = ray_cast(WallSet((arc,)), np.array([1.0, -2.0]), angles, 10.0)
    inside = (angles >= 0.2 + 1e-9) & (angles <= 1.2 - 1e-9)
    outside = (angles < 0.2 - 1e-9) | (angles > 1.2 + 1e-9)
    np.testing.assert_allclose(r[inside], 3.5, atol=1e-12)
    assert np.all(np.isinf(r[outside]))


def test_full_circle_pillar_from_outside_gives_near_side():
    pillar = Arc((5.0, 0.0), 1.0, 0.0, 2 * math.pi)
    r = ray_cast(WallSet((pillar,)), np.zeros(2), np.array([0.0, 0.1, math.pi]), 10.0)
    assert r[0] == pytest.approx(4.0, abs=1e-12)
    # Beam at angle θ: t² − 10 t cos θ + 24 = 0, near root.
    c = math.cos(0.1)
    assert r[1] == pytest.approx(5 * c - math.sqrt(25 * c * c - 24), abs=1e-9)
    assert np.isinf(r[2])


def test_polar_curve_from_its_centre_gives_exactly_r_of_phi():
    angles = np.linspace(0.0, math.pi, 181)
    r = ray_cast(WallSet((PAPER_CURVE,)), np.zeros(2), angles, 8.0)
    np.testing.assert_allclose(r, 5.0 + 0.5 * np.sin(5.0 * angles), rtol=0, atol=1e-9)


def test_beams_that_miss_or_fall_beyond_max_range_return_inf():
    walls = WallSet((Segment((3.0, -1.0), (3.0, 1.0)), PAPER_CURVE))
    # Down (−y) sees nothing: the curve only spans φ ∈ [0, π].
    r = ray_cast(walls, np.zeros(2), np.array([-math.pi / 2, 0.0, math.pi / 2]), 8.0)
    assert np.isinf(r[0])
    assert r[1] == pytest.approx(3.0)
    assert r[2] == pytest.approx(5.5, abs=1e-9)  # r(π/2) = 5 + 0.5 sin(5π/2)
    assert np.all(np.isinf(ray_cast(walls, np.zeros(2), np.array([0.0, math.pi / 2]), 2.9)))


@pytest.mark.parametrize("origin", [(0.0, 0.0), (1.3, 0.7), (-2.0, 1.5), (0.5, 6.5), (3.0, -1.0)])
def test_polar_curve_matches_dense_polyline_from_many_origins(origin):
    angles = np.linspace(-math.pi, math.pi, 721)
    exact = ray_cast(WallSet((PAPER_CURVE,)), np.array(origin), angles, 8.0)
    reference = brute_force_ray_cast([PAPER_CURVE.points(0.005)], origin, angles, 8.0)
    assert np.array_equal(np.isinf(exact), np.isinf(reference)) or _only_grazing_differ(exact, reference)
    both = np.isfinite(exact) & np.isfinite(reference)
    assert both.sum() > 50
    np.testing.assert_allclose(exact[both], reference[both], atol=2e-4)


def _only_grazing_differ(exact, reference):
    """Where one caster hits and the other misses, the beam must be within a hair of an end
    point or tangent; allow at most two such beams."""
    return int(np.sum(np.isinf(exact) != np.isinf(reference))) <= 2


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_every_world_matches_dense_polylines_all_around(name):
    world = WORLDS[name]
    rng = np.random.default_rng(7)
    poses = world.path.sample(0.25)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False) + 0.001
    polylines = world.polylines(0.005)
    for pose in poses[rng.choice(len(poses), size=min(4, len(poses)), replace=False)]:
        exact = world.ray_cast(pose[:2], angles, 8.0)
        reference = brute_force_ray_cast(polylines, pose[:2], angles, 8.0)
        assert _only_grazing_differ(exact, reference)
        both = np.isfinite(exact) & np.isfinite(reference)
        # Chords of 5 mm sag by ≤ 6 µm on a 0.5 m arc; beams near grazing magnify that.
        np.testing.assert_allclose(exact[both], reference[both], atol=5e-4)
        assert np.median(np.abs(exact[both] - reference[both])) < 1e-5


def test_one_origin_per_beam_equals_separate_casts():
    world = WORLDS["mixed"]
    origins = np.array([[3.0, 3.0], [8.0, 2.5], [12.0, 8.0]])
    angles = np.array([0.3, 1.7, -2.0])
    batched = world.ray_cast(origins, angles, 8.0)
    single = [world.ray_cast(o, np.array([a]), 8.0)[0] for o, a in zip(origins, angles)]
    np.testing.assert_array_equal(batched, single)


def test_beam_through_shared_corner_does_not_leak():
    walls = WallSet(rounded_rectangle_walls(0.0, 0.0, 4.0, 2.0, radii=(0.0, 0.0, 0.0, 0.0)))
    r = ray_cast(walls, np.array([2.0, 1.0]), np.array([math.atan2(1.0, 2.0)]), 10.0)
    assert r[0] == pytest.approx(math.hypot(2.0, 1.0), abs=1e-12)


def test_polylines_have_the_requested_spacing_and_lie_on_the_walls():
    arc = Arc((0.0, 0.0), 2.0, 0.0, math.pi)
    for wall in (Segment((0.0, 0.0), (1.0, 1.0)), arc, PAPER_CURVE):
        pts = wall.points(0.1)
        assert np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)) <= 0.1 + 1e-12
    np.testing.assert_allclose(np.linalg.norm(arc.points(0.1), axis=1), 2.0)
    phi = np.arctan2(*PAPER_CURVE.points(0.1)[:, ::-1].T)
    np.testing.assert_allclose(np.linalg.norm(PAPER_CURVE.points(0.1), axis=1), 5.0 + 0.5 * np.sin(5 * np.mod(phi, 2 * np.pi)), atol=1e-12)


def test_invalid_walls_are_refused():
    with pytest.raises(ConfigError):
        Segment((1.0, 1.0), (1.0, 1.0))
    with pytest.raises(ConfigError):
        Arc((0.0, 0.0), -1.0, 0.0, 1.0)
    with pytest.raises(ConfigError):
        PolarCurve((0.0, 0.0), 0.4, 0.5, 5.0, 0.0, 0.0, math.pi)
    with pytest.raises(ConfigError):
        rounded_rectangle_walls(0.0, 0.0, 2.0, 2.0, radii=(1.5, 1.5, 0.0, 0.0))
