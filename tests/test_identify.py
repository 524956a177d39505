"""Identification by stereo points and the model's distances: truth found among clutter, at a bounded count."""
import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from headplod.io import default_marker_model
from headplod.tracking import geometry as geo
from headplod.tracking.identify import (DISTANCE_TOL_PER_FIT_TOL, find_labelings, model_distances,
                                        point_graph, stereo_points)
from headplod.tracking.tracker import TrackerConfig
from headplod.tracking.tracker_rig import RigInUse

MODEL = np.asarray(default_marker_model().points_mm)
TOL_MM = DISTANCE_TOL_PER_FIT_TOL * TrackerConfig().fit_tol_mm


def random_pose(rng, distance_mm):
    """A head facing the cameras, yaw/pitch/roll within ±30°, P1 (mm) in front of the left camera."""
    R = cv2.Rodrigues(np.radians(rng.uniform(-30, 30, 3)))[0] @ np.diag([1.0, -1.0, -1.0])
    return R, np.array([rng.uniform(-80, 250), rng.uniform(-80, 80), distance_mm])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 100_000), st.integers(0, 60))
def test_the_true_labeling_is_found_among_clutter_points_with_noise(seed, clutter):
    """Markers (with 0.5 mm noise) among up to 60 clutter points near the head: the true labeling is among
    those found and no labeling better than it breaks the model by more than the noise allows."""
    rng = np.random.default_rng(seed)
    R, p1 = random_pose(rng, rng.uniform(450, 1400))
    markers = MODEL @ R.T + p1 + rng.normal(0, 0.5, (5, 3))
    points = np.concatenate([markers, p1 + rng.uniform(-300, 300, (clutter, 3))])
    order = rng.permutation(len(points))
    truth = np.argsort(order)[:5]
    found = find_labelings(point_graph(points[order]), model_distances(MODEL), tuple(range(5)), TOL_MM)
    rows = [i for i, row in enumerate(found.index) if np.array_equal(row, truth)]
    assert rows, "the true labeling was not found"
    # Ranked by the shape error.
    assert np.all(np.diff(found.shape_mm) >= 0)


def test_labelings_are_bounded_whatever_the_clutter():
    """The worst case: copies of the markers 1 mm apart, so that nearly every labeling of the copies fits.
    The labelings formed never exceed anchors × per_marker³, however many copies there are."""
    rng = np.random.default_rng(3)
    d = model_distances(MODEL)
    counts = []
    for k in (10, 40, 160):
        points = np.repeat(MODEL, k // 5, axis=0) + rng.normal(0, 1.0, (k // 5 * 5, 3))
        found = find_labelings(point_graph(points), d, tuple(range(5)), TOL_MM, max_anchors=64, per_marker=3)
        counts.append(len(found))
        assert len(found) <= 64 * 3 ** 3
    assert counts[-1] > 0        # the cloud does offer labelings: the bound is what stops them


def test_four_markers_with_one_hidden_are_labelled():
    rng = np.random.default_rng(5)
    R, p1 = random_pose(rng, 700.0)
    markers = MODEL @ R.T + p1
    for hidden in range(5):
        shown = tuple(m for m in range(5) if m != hidden)
        points = np.concatenate([markers[list(shown)], p1 + rng.uniform(-200, 200, (10, 3))])
        found = find_labelings(point_graph(points), model_distances(MODEL), shown, TOL_MM)
        assert np.array_equal(found.index[0], np.arange(4))


def test_stereo_points_pair_projections_and_triangulate_them(sweep12_rig):
    """Projections of 3D points into both cameras of a real rig, shuffled: every true pair is a stereo point
    at its true position; a blob with no partner on its epipolar line makes none."""
    rig = sweep12_rig
    geometry = RigInUse(rig, MODEL, TrackerConfig()).geometry
    rng = np.random.default_rng(0)
    X = rng.uniform([-200, -150, 500], [300, 150, 1200], (12, 3))
    left = geo.project(X, np.eye(3), np.zeros(3), rig.K1, rig.D1)
    right = geo.project(X, rig.R, rig.T, rig.K2, rig.D2)
    right = np.concatenate([right[:-1], [[5.0, 5.0]]])         # the last point's partner is missing
    perm = rng.permutation(len(right))
    xl, xr = geo.undistort(left, rig.K1, rig.D1), geo.undistort(right[perm], rig.K2, rig.D2)
    sp = stereo_points(xl, xr, geometry, TrackerConfig().working_range_mm)
    inverse = np.argsort(perm)
    for i in range(len(X) - 1):
        k = np.flatnonzero((sp.left == i) & (sp.right == inverse[i]))
        assert len(k) == 1
        assert np.linalg.norm(sp.points_mm[k[0]] - X[i]) < 0.5
    assert not np.any(sp.left == len(X) - 1) or np.all(np.linalg.norm(sp.points_mm[sp.left == len(X) - 1]
                                                                      - X[-1], axis=1) > 1.0)
    assert np.all(sp.epipolar_px <= geometry.epipolar_tol_px)


def test_the_trio_must_lie_on_its_image_line_between_its_ends():
    """P1 on the P0-P2 line between them passes; a blob beside the line (a glint standing in for P1) or
    beyond an end does not, whatever the rig."""
    from headplod.tracking.identify import collinear_in_image

    p0, p2 = np.array([100.0, 200.0]), np.array([300.0, 210.0])
    on_line = p0 + 0.5 * (p2 - p0)
    normal = np.array([-10.0, 200.0]) / np.hypot(10.0, 200.0)
    assert collinear_in_image(p0, on_line, p2)
    assert collinear_in_image(p0, on_line + 2.0 * normal, p2)            # centroid noise and lens curvature
    assert not collinear_in_image(p0, on_line + 12.0 * normal, p2)       # a glint beside the markers
    assert not collinear_in_image(p0, p0 + 1.2 * (p2 - p0), p2)          # on the line, beyond an end
