"""The tracker's parts, each built alone and run on a synthetic frame against its ground truth, and the
composition's rules: ``Tracker`` has no base but ``object``, and no attribute is written by two of the
classes it is composed of (an AST check over tracking/).

The synthetic frames are the ``static`` preset at 55 cm (no motion blur, every marker seen), rendered
by the project's renderer (``synth``, tests/conftest.py). Tolerances say what a clean frame at that
distance allows with margin: centres to a few tenths of a pixel, the pose to a millimetre and a
few tenths of a degree (the whole tracker's goals, tests/test_tracker.py, are tighter medians).
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import headplod.tracking as tracking_package
from headplod.tracking import geometry as geo
from headplod.tracking.acquire import Identifier
from headplod.tracking.covariance import Covariance
from headplod.tracking.detection import Detector
from headplod.tracking.frame_checks import FrameChecks, RightPairing, TimeLimits
from headplod.tracking.lock import Lock
from headplod.tracking.motion import HeadMotion
from headplod.tracking.pose_fit import PoseFitter
from headplod.tracking.rig_check import RigChecks
from headplod.tracking.rolling_shutter import RollingShutter
from headplod.tracking.tracker import MarkerPhase, Tracker, TrackerConfig, TrackerParts, make_parts
from headplod.tracking.tracker_rig import RigInUse, RigPhase

TRACKING = Path(tracking_package.__file__).parent
CENTRE_TOL_PX = 0.5          # a clean blob's centroid against its true projection
POSE_TOL_MM, POSE_TOL_DEG = 1.0, 0.3


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(dataset, frames, config, model_mm, axes_G) of a static head at 55 cm."""
    from headplod import io
    from headplod.capture.synthetic import ensure_dataset

    root = tmp_path_factory.mktemp("parts")
    dataset = io.Dataset(ensure_dataset("static", frames=3, root=root, quiet=True, distance_mm=550.0))
    model_mm = np.asarray(dataset.markers.points_mm, dtype=np.float64)
    return dataset, list(dataset), TrackerConfig(), model_mm, geo.model_axes(model_mm)


def _truth(scene, frame):
    """(R_world_G, P1 mm, true centres (2, 5, 2) px) of a frame."""
    dataset, _, _, model_mm, axes_G = scene
    position, axes = dataset.truth[frame.index]
    R = np.asarray(axes).T @ axes_G
    points = (R @ model_mm.T).T + np.asarray(position)
    rig = dataset.rig
    left = geo.project(points, np.eye(3), np.zeros(3), rig.K1, rig.D1)
    right = geo.project(points, rig.R, rig.T, rig.K2, rig.D2)
    return R, np.asarray(position, dtype=np.float64), np.stack([left, right])


def _angle_deg(Ra, Rb) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))))


def _identified(scene, frame):
    """The frame's markers identified by a detector and an identifier of their own, and the rig part."""
    dataset, _, config, model_mm, axes_G = scene
    rig = RigInUse(dataset.rig, model_mm, config)
    blobs = Detector(config).detect((frame.left, frame.right))
    match, reason, _ = Identifier(config, model_mm, axes_G).identify(blobs, rig.geometry)
    assert match is not None, reason
    return match, rig


# ---------------------------------------------------------------------------
# each part alone
# ---------------------------------------------------------------------------


def test_frame_checks_flag_a_repeated_buffer_a_time_jump_and_a_skewed_right_camera(scene):
    dataset, frames, config, _, _ = scene
    checks = FrameChecks(TimeLimits.of(config))
    f = frames[0]
    assert checks.check_images(f.left, f.right, dataset.rig.image_size) is None
    wrong = checks.check_images(f.left[:-2], f.right, dataset.rig.image_size)
    assert wrong is not None and "wrong camera mode" in wrong
    assert checks.repeated_images(f.left, f.right) is None
    repeat = checks.repeated_images(f.left, f.right)               # the very buffers again
    assert repeat is not None and "both cameras" in repeat
    assert checks.repeated_images(frames[1].left, frames[1].right) is None
    for k in range(6):                                               # a steady 30 Hz clock
        verdict = checks.check_time(k / 30)
        assert verdict.notes == [] and not verdict.glitch and not verdict.discontinuity
    assert checks.frame_period() == pytest.approx(1 / 30)
    same = checks.check_time(5 / 30)                                 # the same time again
    assert same.time_glitch and same.glitch and "repeats" in same.notes[0]
    back = checks.check_time(1 / 30)
    assert back.discontinuity and "went back" in back.notes[0] and checks.time_jumps == 1
    ahead = checks.check_time(100.0)
    assert ahead.discontinuity and "jumped" in ahead.notes[0] and checks.time_jumps == 2
    assert checks.implausible_offset(1.0, 1.004) is None            # a few ms: a stereo pair
    skew = checks.implausible_offset(1.0, 6.0)
    assert skew is not None and "5.0 s after" in skew


def test_right_pairing_keeps_the_pair_until_an_offset_is_estimated(scene):
    _, frames, _, _, _ = scene
    pairing = RightPairing()
    f = frames[0]
    images, t_right = pairing.pair(f.left, f.right, 0.0, 0.004, None)
    assert images[0] is f.left and images[1] is f.right and t_right == 0.004
    assert pairing.declared_right == 0.004
    pairing.reset()
    assert pairing.declared_right is None


def test_detector_finds_the_five_markers_near_their_true_projections(scene):
    _, frames, config, _, _ = scene
    frame = frames[0]
    _, _, true_px = _truth(scene, frame)
    detector = Detector(config)
    blobs = detector.detect((frame.left, frame.right))
    for cam in range(2):
        centres = blobs[cam].centers_px
        assert len(centres) >= 5
        distance = np.linalg.norm(centres[None, :, :] - true_px[cam][:, None, :], axis=2)   # (5, n)
        assert distance.min(axis=1).max() < CENTRE_TOL_PX, (cam, distance.min(axis=1))
        assert detector.backgrounds[cam] is not None
    # The track state's re-measure, from a lock on the true centres, finds them again.
    detector.keep_thresholds(blobs)
    lock = Lock(true_px, None, np.full((2, 5), 1.5), None)
    again = detector.remeasure((frame.left, frame.right), lock)
    assert again is not None
    assert np.abs(again.centers - true_px).max() < CENTRE_TOL_PX


def test_identifier_labels_the_markers_as_the_truth_does(scene):
    _, frames, _, _, _ = scene
    frame = frames[0]
    _, _, true_px = _truth(scene, frame)
    match, _ = _identified(scene, frame)
    assert match.visible.all()
    # Each label on its own marker: the labelled centre is the true projection of that marker.
    assert np.abs(match.centers - true_px).max() < CENTRE_TOL_PX
    assert np.all(match.epipolar < 1.0)


def test_pose_fitter_recovers_the_true_pose(scene):
    _, frames, config, model_mm, axes_G = scene
    frame = frames[0]
    R_true, p1_true, _ = _truth(scene, frame)
    match, rig = _identified(scene, frame)
    motion = HeadMotion(config)
    checks = RigChecks(config, model_mm)
    fitter = PoseFitter(config, model_mm, axes_G, rig, motion, RollingShutter(config, model_mm, rig, motion), checks)
    timings = {}
    fit = fitter.fit(match, frame.t, None, timings)
    assert fit.reason is None and fit.withheld is None
    assert np.linalg.norm(fit.p1 - p1_true) < POSE_TOL_MM
    assert _angle_deg(fit.R, R_true) < POSE_TOL_DEG
    assert np.nanmax(fit.residuals) < config.reproj_tol_px
    assert {"pose", "verify"} <= set(timings)
    assert not fit.compensated and not fit.uncompensated      # no right offset to compensate
    # The checks alone: the fit passes; a centre moved by 10 px does not.
    assert checks.verify(fit.R, fit.p1, fit.residuals, None, match) is None
    bad = fit.residuals.copy()
    bad[1, 3] = 10.0
    reason = checks.verify(fit.R, fit.p1, bad, None, match)
    assert reason is not None and "P3 in the right image" in reason


def test_covariance_of_v_is_positive_definite(scene):
    dataset, frames, config, model_mm, axes_G = scene
    frame = frames[0]
    match, rig = _identified(scene, frame)
    motion = HeadMotion(config)
    checks = RigChecks(config, model_mm)
    fitter = PoseFitter(config, model_mm, axes_G, rig, motion, RollingShutter(config, model_mm, rig, motion), checks)
    fit = fitter.fit(match, frame.t, None, {})
    detector = Detector(config)
    detector.detect((frame.left, frame.right))
    covariance = Covariance(config, model_mm, axes_G, dataset.rig, checks)
    cov_input = covariance.input((frame.left, frame.right), match, fit, frame.t, None, 0.0, None,
                                 detector.backgrounds, detector.thresholds, rig)
    cov = covariance.estimate(cov_input)
    assert cov.shape == (2, 2) and np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # V known to well under a degree from a clean frame at 55 cm.
    assert np.sqrt(np.linalg.eigvalsh(cov)[-1]) < 0.5
    assert covariance.centre_sd(cov_input, match).shape == (2, 5, 2)


def test_rig_in_use_widens_the_tolerances_once_refining_and_names_its_phase(scene):
    dataset, _, config, model_mm, _ = scene
    seen = []
    rig = RigInUse(dataset.rig, model_mm, config, on_change=seen.append)
    assert seen == [dataset.rig] and rig.phase() is RigPhase.YAML
    assert rig.geometry.epipolar_tol_px == config.epipolar_tol_px and rig.cov() is None and rig.version() == 0
    rig.start_refiner(None)
    P = rig.cov()
    assert P.shape == (9, 9) and np.all(np.linalg.eigvalsh(P) > 0)
    assert rig.geometry.rig_sigma_px > 0
    assert rig.geometry.epipolar_tol_px > config.epipolar_tol_px and rig.geometry.fit_tol_mm > config.fit_tol_mm
    assert rig.phase() is RigPhase.YAML and rig.message() is None     # no update yet


def test_head_motion_takes_a_velocity_and_refuses_one_no_head_has(scene):
    _, _, config, _, _ = scene
    motion = HeadMotion(config)
    R0 = np.eye(3)
    for k in range(4):                                     # P1 moving 30 mm/s along x
        assert motion.remember(k / 30, R0, np.array([k, 0.0, 600.0]), 0, None, None, False) is None
    omega, v = motion.history.velocity()
    assert np.allclose(v, [30.0, 0.0, 0.0], atol=1e-6) and np.allclose(omega, 0.0, atol=1e-9)
    assert not motion.motion_unknown
    note = motion.remember(4 / 30, R0, np.array([500.0, 0.0, 600.0]), 0, None, None, False)   # 15 m/s
    assert note is not None and "not a motion a head makes" in note and motion.times_suspect
    assert motion.remember(5 / 30, R0, np.array([0.0, 0.0, 600.0]), 0, None, None, True) is None  # a glitch


def test_rolling_shutter_row_times_and_given_readout(scene):
    dataset, _, _, model_mm, _ = scene
    config = TrackerConfig(readout_s=0.02)
    rig = RigInUse(dataset.rig, model_mm, config)
    shutter = RollingShutter(config, model_mm, rig, HeadMotion(config))
    assert shutter.readout_s() == pytest.approx(0.02)               # no refinement: the given one
    height = dataset.rig.image_size[1]
    centres = np.zeros((2, 5, 2))
    centres[..., 1] = [[0.0, (height - 1) / 2, height - 1, 0.0, 0.0]] * 2
    delay = shutter.row_times(centres, 0.02)
    assert delay[0, 0] == pytest.approx(-0.01) and delay[0, 1] == pytest.approx(0.0)
    assert delay[0, 2] == pytest.approx(0.01)


def test_a_tracker_of_given_parts_tracks_and_names_its_state(scene):
    dataset, frames, config, model_mm, axes_G = scene
    parts = make_parts(dataset.rig, model_mm, axes_G, config)
    assert isinstance(parts, TrackerParts)
    tracker = Tracker(dataset.rig, dataset.markers, config, parts=parts)
    assert tracker.parts is parts and tracker.state() == ("acquire", "rig.yaml")
    for frame in frames:
        R_true, p1_true, _ = _truth(scene, frame)
        result = tracker.process(frame.left, frame.right, frame.t)
        assert result.ok, result.reason
        assert np.linalg.norm(result.position_mm - p1_true) < POSE_TOL_MM
        assert _angle_deg(result.R_world_G, R_true) < POSE_TOL_DEG
    assert result.mode == "track" and tracker.state()[0] == "track"
    assert tracker._markers.phase is MarkerPhase.TRACK


# ---------------------------------------------------------------------------
# the composition's rules
# ---------------------------------------------------------------------------

def _self_writes(cls: ast.ClassDef) -> set[str]:
    """Attribute names a class writes on ``self`` (its methods' first argument): assigned, augmented,
    annotated, deleted, or a target of for/with/walrus."""
    names = set()
    for func in ast.walk(cls):
        if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef)) or not func.args.args:
            continue
        me = func.args.args[0].arg
        for node in ast.walk(func):
            targets = []
            if isinstance(node, ast.Assign):
                targets = node.targets
            elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
                targets = [node.target]
            elif isinstance(node, ast.Delete):
                targets = node.targets
            elif isinstance(node, (ast.For, ast.AsyncFor)):
                targets = [node.target]
            elif isinstance(node, ast.withitem) and node.optional_vars is not None:
                targets = [node.optional_vars]
            for target in targets:
                for sub in ast.walk(target):
                    if (isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name)
                            and sub.value.id == me):
                        names.add(sub.attr)
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("setattr",)
                    and node.args and isinstance(node.args[0], ast.Name) and node.args[0].id == me):
                names.add("<setattr>")
    return names


def _tracking_classes() -> dict[str, ast.ClassDef]:
    classes = {}
    for path in sorted(TRACKING.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                classes[node.name] = node
    return classes


def test_the_tracker_has_no_base_but_object_and_no_mixins_in_tracking():
    assert Tracker.__bases__ == (object,)
    for part in _built_parts():
        assert type(part).__bases__ == (object,), type(part)
    for name, node in _tracking_classes().items():
        bases = [ast.unparse(b) for b in node.bases]
        # Classes in tracking/ derive from object, a value type or an enum, never from one another's
        # parts (a mixin).
        assert all(b in ("NamedTuple", "enum.Enum", "Enum", "Exception", "ValueError", "Protocol") for b in bases), (name, bases)


def test_each_attribute_of_the_tracker_and_its_parts_is_written_by_one_class():
    composed = {"Tracker", *(type(part).__name__ for part in _built_parts())}
    classes = _tracking_classes()
    assert composed <= set(classes), composed - set(classes)
    writers: dict[str, list[str]] = {}
    for name in sorted(composed):
        for attr in _self_writes(classes[name]):
            writers.setdefault(attr, []).append(name)
    assert "<setattr>" not in writers, writers.get("<setattr>")
    shared = {attr: names for attr, names in writers.items() if len(names) > 1}
    assert not shared, f"attributes written by more than one class of the tracker: {shared}"
    # The check sees writes: each part writes its own state.
    assert "_markers" in writers and writers["_markers"] == ["Tracker"]
    assert writers["refiner"] == ["RigInUse"] and writers["time_jumps"] == ["FrameChecks"]


def _built_parts() -> TrackerParts:
    """The default parts, for the shared sample's rig and marker model."""
    from headplod import io

    dataset = io.Dataset(Path(__file__).parent / "data" / "sweep12")
    model_mm = np.asarray(dataset.markers.points_mm, dtype=np.float64)
    return make_parts(dataset.rig, model_mm, geo.model_axes(model_mm), TrackerConfig())
