"""Clutter (issue 34): the synthetic 'clutter' scenes, and the identification's cost against blobs per image.

The clutter is 3D points both cameras see (synthetic.clutter), so each clutter blob in one image has its
partner on the epipolar line in the other: checked here against the rig's own epipolar geometry, and the
detector must find every marker and every clutter object as its own blob. Then the identification's cost
is counted (``TrackResult.hypotheses``), never timed.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from headplod.live.loop import result_record
from headplod.tracking import evaluate
from headplod.tracking.detect import detect_blobs, estimate_background
from headplod.tracking.tracker import Tracker, TrackerConfig
from synthetic.clutter import reflector_image_points
from synthetic.render import project_points, render_pair, rig_cameras
from synthetic.scenes import make_scene

#: Blob counts of the sweep (5: the markers alone).
SWEEP = (5, 10, 20, 30, 45, 60)


def _epipolar_px(setup, left_uv: np.ndarray, right_uv: np.ndarray) -> np.ndarray:
    """Distance (px, in the right image's normalized coordinates times its focal length) of each right point
    from the epipolar line of its left point, through the rig's distortion: (k,)."""
    cams = rig_cameras(setup)
    xl = cv2.undistortPoints(left_uv.reshape(-1, 1, 2), cams[0].K, cams[0].D).reshape(-1, 2)
    xr = cv2.undistortPoints(right_uv.reshape(-1, 1, 2), cams[1].K, cams[1].D).reshape(-1, 2)
    R, T = cams[1].R, cams[1].t
    E = np.array([[0, -T[2], T[1]], [T[2], 0, -T[0]], [-T[1], T[0], 0]]) @ R
    hl = np.column_stack([xl, np.ones(len(xl))])
    hr = np.column_stack([xr, np.ones(len(xr))])
    lines = hl @ E.T                                     # epipolar lines in the right view
    return np.abs(np.einsum("ij,ij->i", hr, lines)) / np.hypot(lines[:, 0], lines[:, 1]) * cams[1].K[0, 0]


def test_clutter_is_seen_by_both_cameras_on_the_epipolar_geometry_and_detected_blob_by_blob():
    scene = make_scene("clutter", n_frames=3, blobs=30, seed=2)
    assert len(scene.options.reflectors) == 25
    for t in scene.times[[0, 2]]:
        uv = reflector_image_points(scene.setup, scene.options.reflectors, scene.pose_fn, t)
        assert np.isfinite(uv).all()
        # 3D points: every left/right pair on its epipolar line (projection rounding only)
        assert _epipolar_px(scene.setup, uv[0], uv[1]).max() < 1e-6
        # and not independent specks: a left point against another object's right point is far off its line
        shuffled = _epipolar_px(scene.setup, uv[0], np.roll(uv[1], 1, axis=0))
        assert np.median(shuffled) > 5.0
        markers = scene.marker_positions(t)
        left, right = render_pair(scene.setup, scene.model_points_mm, scene.diameter_mm, scene.pose_fn, t,
                                  scene.options, np.random.default_rng(7))
        for cam, image in enumerate((left, right)):
            truth = np.vstack([project_points(rig_cameras(scene.setup)[cam], markers), uv[cam]])     # (30, 2)
            blobs = detect_blobs(image, background=estimate_background(image))
            d = np.linalg.norm(blobs.centers_px[:, None, :] - truth[None, :, :], axis=2)
            nearest = d.argmin(axis=0)
            # each marker and clutter object is its own blob, centred on its true image
            assert d.min(axis=0).max() < 0.5, d.min(axis=0)
            assert len(set(nearest.tolist())) == len(truth)
            assert len(truth) <= len(blobs) <= len(truth) + 1      # at most one noise speck or split blob


def test_clutter_is_seeded_and_a_larger_count_adds_objects():
    small = make_scene("clutter", n_frames=4, blobs=10, seed=1).options.reflectors
    large = make_scene("clutter", n_frames=4, blobs=45, seed=1).options.reflectors
    again = make_scene("clutter", n_frames=4, blobs=45, seed=1).options.reflectors
    other = make_scene("clutter", n_frames=4, blobs=45, seed=2).options.reflectors
    assert large == again and large != other
    assert large[:len(small)] == small and len(large) == 40
    kinds = {r.kind for r in large}
    assert any(r.on_head for r in large) and len(kinds) >= 4     # the glasses' metal and the room's things
    assert make_scene("clutter", n_frames=4, blobs=5).options.reflectors == ()
    with pytest.raises(ValueError):
        make_scene("clutter", n_frames=4, blobs=4)


def test_clutter_on_the_glasses_moves_with_the_head():
    scene = make_scene("clutter", n_frames=40, blobs=10, seed=0)
    head = [r for r in scene.options.reflectors if r.on_head]
    room = [r for r in scene.options.reflectors if not r.on_head]
    assert head and room
    t0, t1 = scene.times[0], scene.times[-1]
    for r in head:      # fixed in G: its distance to P1 stays, while P1 moves
        d0 = np.linalg.norm(r.world_position(scene.pose_fn, t0) - scene.pose_fn(t0)[1])
        d1 = np.linalg.norm(r.world_position(scene.pose_fn, t1) - scene.pose_fn(t1)[1])
        assert d0 == pytest.approx(d1, abs=1e-9)
        assert np.linalg.norm(r.world_position(scene.pose_fn, t0) - r.world_position(scene.pose_fn, t1)) > 1.0
    for r in room:
        np.testing.assert_array_equal(r.world_position(scene.pose_fn, t0), r.world_position(scene.pose_fn, t1))


@pytest.mark.slow
def test_identification_cost_grows_at_most_linearly_with_clutter_and_finds_the_pose(synth):
    """Acquire one frame at each blob count: the pose found and right, and the hypotheses scored at N blobs at
    most linear in N past the 10-blob case (counted, not timed)."""
    hypotheses, problems = {}, []
    for n in SWEEP:
        dataset = synth("clutter", 1, blobs=n)
        frame = next(iter(dataset))
        result = Tracker(dataset.rig, dataset.markers, TrackerConfig(track=False)).process(
            frame.left, frame.right, frame.t, frame.t_right)
        assert result.mode == "acquire"
        assert min(len(b) for b in result.blobs) >= n          # the clutter reached the identification
        hypotheses[n] = result.hypotheses
        errors = evaluate.pose_errors([result_record(frame, result, extras=False)], dataset.truth)
        if not result.ok:
            problems.append(f"{n} blobs: no pose ({result.reason})")
        elif errors["v_err_deg"][0] > evaluate.WRONG_IDENTIFICATION_DEG or errors["pos_err_mm"][0] > 20.0:
            problems.append(f"{n} blobs: wrong pose (V {errors['v_err_deg'][0]:.1f}° off)")
    # Linear past the 10-blob case, with a floor of 10 hypotheses there: an identification that scores a
    # handful at 10 blobs may score a few dozen at 60, not thousands.
    reference = max(hypotheses[10], 10)
    # And the ranking, not the budget, keeps it small: no frame fitted the whole budget.
    budget = TrackerConfig().max_hypotheses
    problems += [f"{n} blobs: the budget ({budget}) was spent" for n, h in hypotheses.items() if h >= budget]
    for n in SWEEP:
        if n > 10 and hypotheses[n] > 3 * reference * n / 10:
            problems.append(f"{n} blobs: {hypotheses[n]} hypotheses, more than 3 x {reference} x {n}/10")
    assert not problems, f"hypotheses {hypotheses}; " + "; ".join(problems)
