"""Fuzz of ``Tracker.process`` (issue 21): rigs, clocks and streams that are not what they claim.

The images come from the project's independent renderer (:mod:`synthetic`):
two head motions rendered once per module on a 120 Hz grid with the true
rig. A 30 fps stream takes every fourth grid image as its left image, and
its right image from the same grid up to four steps (one frame period)
before or after: an exposure offset, declared or not, costs no rendering.
Everything else is perturbed cheaply per case with a fixed seed: the rig
the tracker is given (a stale ``rig.yaml``: the right camera turned up to
3°, the baseline up to 10% off), the times (jitter, repeats, jumps), the
stream (dropped, repeated, reordered frames, left and right swapped) and
the images (salt noise, bright extra blobs); the rig's refinement on and off.

What must hold for every frame of every case:

- no exception escapes ``process`` and none is isolated by it
  (``tracker.internal_errors == 0``: the isolation must not hide bugs);
- a pose reported ``ok`` is within 20 mm (P1) and 5° (V) of the truth at
  the left image's time. Why those bounds: they are outside the honest
  errors of every case here (tenths of a mm and degree on clean streams;
  up to ~10 mm and ~3° on a stale rig before its refinement, where the
  pose's covariance says so: V's σ is capped at 2°) and inside what a
  wrong identification, a diverged fit or a motion model extrapolated past
  its evidence gives (tens to hundreds of mm, tens of degrees).

Budget: ~2,400 frames, ~15-25 s on two busy cores, most of it tracking;
the two renders take ~3 s.

The fraction of frames tracked per class is printed (``pytest -s``), and
floored for the classes whose evidence supports a pose on most frames, so
that refusing everything does not pass.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.tracking.motion import PoseHistory
from headplod.tracking.pose_fit import PoseFitter
from headplod.tracking.rig_estimator import RigEstimator
from headplod.tracking.rig_refine import RigRefineConfig
from headplod.tracking.tracker import Tracker, TrackerConfig

GRID_HZ = 120.0        # the render grid, Hz
STEP = 4               # grid steps per frame of the tracked stream: 30 fps
FRAMES = 30            # frames per case
MAX_POS_MM = 20.0      # an ok pose's largest P1 error, mm (module docstring)
MAX_V_DEG = 5.0        # an ok pose's largest V error, deg
SEED = 21

#: (preset, grid images): a user reading around the screen, and a ±45° yaw sweep (up to 140°/s).
BASES = (("looking_around", 160), ("yaw_sweep", 160))


@dataclasses.dataclass
class Grid:
    """One head motion rendered on the 120 Hz grid with the true rig.

    left, right : (n, H, W) uint8; p1 : (n, 3) mm; v : (n, 3) V in the
    world (left camera) frame, at each grid time; times : (n,) s.
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    p1: np.ndarray
    v: np.ndarray
    times: np.ndarray
    rig: io.Rig
    markers: io.MarkerModel


def _render(preset: str, n: int, seed: int) -> Grid:
    from synthetic import scenes
    from synthetic.render import render_pair

    sc = scenes.make_scene(preset, n_frames=n, seed=seed, fps=GRID_HZ)
    left, right, p1, v = [], [], [], []
    for k, t in enumerate(sc.times):
        lk, rk = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, t, sc.options,
                             np.random.default_rng([seed, k]))
        pos, axes = sc.truth(t)
        left.append(lk), right.append(rk), p1.append(pos), v.append(axes[2])
    s = sc.setup
    rig = io.Rig(tuple(s.image_size), s.K1, s.D1, s.K2, s.D2, s.R, s.T)
    markers = io.MarkerModel(np.asarray(sc.model_points_mm, float), float(sc.diameter_mm))
    return Grid(preset, np.stack(left), np.stack(right), np.stack(p1), np.stack(v), np.asarray(sc.times),
                rig, markers)


@pytest.fixture(scope="module")
def grids():
    """The base motions, rendered once for the module (~3 s: 320 stereo pairs at 640x480)."""
    return [_render(name, n, SEED + i) for i, (name, n) in enumerate(BASES)]


# ---------------------------------------------------------------------------
# one case: a stream of frames made from the grid, and the tracker's settings
# ---------------------------------------------------------------------------

@dataclasses.dataclass
class FrameSpec:
    """One frame as given to the tracker: grid indices of its images, its times, and image damage."""

    left: int
    right: int
    t: float
    t_right: float | None = None
    swap: bool = False           # left and right images exchanged
    salt: float = 0.0            # fraction of pixels set bright
    blobs: int = 0               # bright extra blobs per image


@dataclasses.dataclass
class Case:
    cls: str
    grid: int
    frames: list
    refine: bool
    turn_deg: float = 0.0        # the stale rig.yaml: right camera turned by this since ...
    baseline_scale: float = 1.0  # ... and its baseline this times the true one
    seed: int = 0


def _stale_rig(rig: io.Rig, turn_deg: float, baseline_scale: float, rng) -> io.Rig:
    """rig.yaml written before the right camera turned by ``turn_deg`` (random axis) and with the baseline
    ``baseline_scale`` times the true one: the tracker is given this, the images show ``rig``."""
    axis = rng.normal(size=3)
    turn = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(turn_deg))[0]
    return io.Rig(rig.image_size, rig.K1, rig.D1, rig.K2, rig.D2, turn.T @ rig.R,
                  turn.T @ np.reshape(rig.T, 3) * baseline_scale)


def _stream(rng, n_grid: int, frames: int = FRAMES, offset_steps: int = 0, declared: bool = False):
    """A 30 fps stream from a random start: the right image ``offset_steps`` grid steps from the left."""
    lo = max(0, -offset_steps)
    hi = n_grid - STEP * frames - max(offset_steps, 0)
    start = int(rng.integers(lo, max(hi, lo + 1)))
    out = []
    for k in range(frames):
        i = start + STEP * k
        t = i / GRID_HZ
        out.append(FrameSpec(i, i + offset_steps, t, (i + offset_steps) / GRID_HZ if declared else None))
    return out


def _case(cls: str, rng, n_grid: int) -> list:
    """The frames of one case of a class (see the module docstring)."""
    if cls in ("offset declared", "offset undeclared"):
        m = int(rng.choice([-4, -3, -2, -1, 1, 2, 3, 4]))
        return _stream(rng, n_grid, offset_steps=m, declared=cls == "offset declared")
    fr = _stream(rng, n_grid)
    if cls == "jitter":
        sd = rng.uniform(0.002, 0.010)          # s: up to a third of a frame period
        for f in fr:
            f.t += float(rng.normal(0, sd))
    elif cls == "jitter + offset":
        m = int(rng.integers(-4, 5))
        sd = rng.uniform(0.001, 0.008)
        fr = _stream(rng, n_grid, offset_steps=m, declared=True)
        for f in fr:
            f.t += float(rng.normal(0, sd))
            f.t_right = f.t + m / GRID_HZ + float(rng.normal(0, sd))
    elif cls == "repeated times":
        for k in range(1, len(fr)):
            if rng.random() < 0.25:
                fr[k].t = fr[k - 1].t
    elif cls == "close times":
        # Two frames 1 ms apart (the 364 mm case), with the right image's time given.
        m = int(rng.integers(-4, 5))
        fr = _stream(rng, n_grid, offset_steps=m, declared=True)
        for k in range(1, len(fr)):
            if rng.random() < 0.3:
                fr[k].t = fr[k - 1].t + 0.001
            fr[k].t_right = fr[k].t + m / GRID_HZ
    elif cls == "time jumps":
        for k in sorted(rng.choice(np.arange(6, len(fr)), size=2, replace=False)):
            jump = float(rng.choice([-1, 1]) * rng.uniform(0.2, 3.0))
            for f in fr[k:]:
                f.t += jump
                f.t_right = None if f.t_right is None else f.t_right + jump
    elif cls == "dropped frames":
        fr = [f for f in fr if rng.random() > 0.25]
    elif cls == "repeated frames":
        out = []
        for f in fr:
            out.append(f)
            if rng.random() < 0.2:
                g = dataclasses.replace(f)
                if rng.random() < 0.5:
                    g.t += 1.0 / 30          # the same images again, with the next time
                out.append(g)
        fr = out
    elif cls == "swapped frames":
        for k in range(len(fr) - 1):
            if rng.random() < 0.12:
                if rng.random() < 0.5:
                    fr[k], fr[k + 1] = fr[k + 1], fr[k]      # order swapped, times and all: time goes back
                else:
                    fr[k].swap = True                        # left and right images exchanged
    elif cls == "salt and blobs":
        for f in fr:
            f.salt = float(rng.choice([0.0, rng.uniform(1e-4, 2e-3)]))
            f.blobs = int(rng.integers(0, 4))
    elif cls == "everything":
        m = int(rng.integers(-4, 5))
        fr = _stream(rng, n_grid, offset_steps=m, declared=bool(rng.random() < 0.5))
        out = []
        for f in fr:
            if rng.random() < 0.1:
                continue
            f.t += float(rng.normal(0, 0.003))
            if f.t_right is not None:
                f.t_right = f.t + m / GRID_HZ
            f.swap = bool(rng.random() < 0.05)
            f.salt = float(rng.choice([0.0, 5e-4]))
            f.blobs = int(rng.integers(0, 3))
            out.append(f)
            if rng.random() < 0.05:
                out.append(dataclasses.replace(f))
        fr = out
    return fr


#: (class, cases, floor of the fraction of frames tracked or None). The floors are for the classes where
#: the images support a pose on most frames; they sit 10-20 points below what the tracker does (printed),
#: so that a change that refuses honest poses fails, not one that moves a case by a frame or two. None: a
#: stale rig 3° or 10% off is outside the rig's error model (0.5°, 2%: refused or withheld until refined,
#: and refinement does not always get there in 30 frames).
CLASSES = [
    ("clean", 4, 0.95),
    ("stale rig", 8, None),
    ("jitter", 6, 0.90),
    ("repeated times", 4, 0.85),
    ("close times", 6, 0.60),
    ("time jumps", 4, 0.85),
    ("offset declared", 8, 0.75),
    ("offset undeclared", 8, 0.75),
    ("jitter + offset", 6, 0.70),
    ("dropped frames", 4, 0.85),
    # A repeated buffer (the same images again, a fifth of the frames) is refused: its images were
    # exposed a frame before its time.
    ("repeated frames", 4, 0.65),
    ("swapped frames", 6, 0.75),
    ("salt and blobs", 6, 0.75),
    ("everything", 8, 0.40),
]


def make_cases(grids, classes=CLASSES, seed: int = SEED) -> list:
    rng = np.random.default_rng(seed)
    cases = []
    for cls, n, _ in classes:
        for j in range(n):
            g = j % len(grids)
            # 'stale rig': up to 3° and 10%, far outside the rig's error model (0.5°, 2% at 1σ);
            # 'everything': within it, so that the other faults at once are what is tested.
            turn, scale = {"stale rig": (3.0, 0.1), "everything": (0.5, 0.02)}.get(cls, (0.0, 0.0))
            frames = _case(cls, rng, len(grids[g].times))
            cases.append(Case(cls, g, frames, refine=bool((j // len(grids)) % 2 == 0),
                              turn_deg=float(rng.uniform(0, turn)),
                              baseline_scale=float(rng.uniform(1 - scale, 1 + scale)),
                              seed=int(rng.integers(1 << 30))))
    return cases


def _damage(img: np.ndarray, salt: float, blobs: int, rng) -> np.ndarray:
    """Salt noise (that fraction of pixels at 200-255 DN) and bright Gaussian blobs (σ 0.8-2.5 px)."""
    if not salt and not blobs:
        return img
    out = img.copy()
    h, w = img.shape
    n = int(salt * h * w)
    if n:
        out[rng.integers(0, h, n), rng.integers(0, w, n)] = rng.integers(200, 256, n, dtype=np.uint8)
    if blobs:
        canvas = np.zeros((h, w), np.float32)
        for _ in range(blobs):
            x, y = rng.uniform(20, w - 20), rng.uniform(20, h - 20)
            s, peak = rng.uniform(0.8, 2.5), rng.uniform(120, 255)
            x0, x1, y0, y1 = int(x - 4 * s), int(x + 4 * s) + 1, int(y - 4 * s), int(y + 4 * s) + 1
            yy, xx = np.mgrid[y0:y1, x0:x1]
            canvas[y0:y1, x0:x1] += peak * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s * s))
        out = np.clip(out + canvas, 0, 255).astype(np.uint8)
    return out


def run_case(case: Case, grid: Grid):
    """Track one case: per frame (ok, reason, P1 error mm, V error deg), and the tracker."""
    rng = np.random.default_rng(case.seed)
    rig = grid.rig
    if case.turn_deg or case.baseline_scale != 1.0:
        rig = _stale_rig(rig, case.turn_deg, case.baseline_scale, rng)
    config = TrackerConfig(rig_refine=RigRefineConfig(enabled=case.refine))
    tracker = Tracker(rig, grid.markers, config)
    out = []
    for f in case.frames:
        left, right = grid.left[f.left], grid.right[f.right]
        if f.swap:
            left, right = right, left
        left, right = _damage(left, f.salt, f.blobs, rng), _damage(right, f.salt, f.blobs, rng)
        r = tracker.process(left, right, f.t, f.t_right)
        assert "total" in r.timings_s
        if r.ok:
            pos = float(np.linalg.norm(r.position_mm - grid.p1[f.left]))
            ang = float(np.degrees(np.arccos(np.clip(r.axes[2] @ grid.v[f.left], -1, 1))))
        else:
            pos = ang = float("nan")
        out.append((r.ok, r.reason, pos, ang))
    return out, tracker


def _describe(case: Case, k: int, f: FrameSpec) -> str:
    return (f"{case.cls} (grid {case.grid}, refine {case.refine}, turn {case.turn_deg:.2f}°, "
            f"baseline x{case.baseline_scale:.3f}, seed {case.seed}) frame {k}: {f}")


@pytest.mark.slow
def test_fuzz_tracker(grids):
    cases = make_cases(grids)
    tracked, wrong, errors = {}, [], []
    for case in cases:
        results, tracker = run_case(case, grids[case.grid])
        if tracker.internal_errors:
            errors.append(f"{case.cls} (seed {case.seed}): {tracker.internal_errors} internal errors, "
                          f"first {tracker.first_internal_error}")
        n_ok, n = tracked.get(case.cls, (0, 0))
        tracked[case.cls] = (n_ok + sum(r[0] for r in results), n + len(results))
        for k, (ok, _, pos, ang) in enumerate(results):
            if ok and not (pos <= MAX_POS_MM and ang <= MAX_V_DEG):
                wrong.append(f"{_describe(case, k, case.frames[k])}: {pos:.1f} mm, {ang:.1f}°")
    print("\nfraction of frames tracked per perturbation class:")
    for cls, (n_ok, n) in tracked.items():
        print(f"  {cls:20s} {n_ok / n:6.1%} of {n}")
    assert not errors, "\n".join(errors)
    assert not wrong, f"{len(wrong)} wrong ok poses:\n" + "\n".join(wrong[:20])
    for cls, _, floor in CLASSES:
        if floor is not None:
            n_ok, n = tracked[cls]
            assert n_ok / n >= floor, (cls, n_ok / n)


# ---------------------------------------------------------------------------
# fault isolation (Tracker.process)
# ---------------------------------------------------------------------------

FAULT_FRAME = 5        # the frame whose processing raises


def _stream_frames(grid: Grid, n: int, start: int = 40):
    """n frames of a 30 fps stream from the grid, synchronous cameras: (left, right, t, grid index)."""
    return [(grid.left[i], grid.right[i], i / GRID_HZ, i) for i in range(start, start + STEP * n, STEP)]


def _errors(result, grid: Grid, i: int):
    """(P1 error mm, V error deg) of an ok result against the truth at grid image i."""
    return (float(np.linalg.norm(result.position_mm - grid.p1[i])),
            float(np.degrees(np.arccos(np.clip(result.axes[2] @ grid.v[i], -1, 1)))))


@pytest.mark.slow
@pytest.mark.parametrize("exc", [
    np.linalg.LinAlgError("Singular matrix"),
    cv2.error("(-215:Assertion failed) 0 <= i in function 'solve'"),
    ZeroDivisionError("float division by zero"),
    MemoryError("cannot allocate 12 MiB"),
    RuntimeError("the fit went nowhere"),
], ids=lambda e: type(e).__name__)
def test_an_exception_costs_its_frame_only(grids, monkeypatch, exc):
    grid = grids[0]
    frame = {"k": None}
    estimate = PoseFitter.estimate

    def failing(self, *args, **kwargs):
        if frame["k"] == FAULT_FRAME:
            raise exc
        return estimate(self, *args, **kwargs)

    monkeypatch.setattr(PoseFitter, "estimate", failing)
    tracker = Tracker(grid.rig, grid.markers)
    results = []
    for k, (left, right, t, i) in enumerate(_stream_frames(grid, 12)):
        frame["k"] = k
        results.append((tracker.process(left, right, t), i))
    bad, _ = results[FAULT_FRAME]
    expected = f"internal error: {type(exc).__name__}: {exc}"
    assert not bad.ok and bad.reason == expected and "total" in bad.timings_s
    assert tracker.internal_errors == 1 and tracker.first_internal_error == expected
    assert type(exc).__name__ in tracker.first_internal_traceback
    # Every other frame is tracked, to the accuracy of a clean stream (0.5 mm, 0.3°: ~10x its noise);
    # the one after the fault is acquired afresh (the state was reset).
    for k, (r, i) in enumerate(results):
        if k != FAULT_FRAME:
            pos, ang = _errors(r, grid, i)
            assert r.ok and pos < 0.5 and ang < 0.3, (k, r.reason, pos, ang)
    assert results[FAULT_FRAME + 1][0].mode == "acquire"


@pytest.mark.slow
def test_an_exception_in_the_refinement_drops_its_chunk_and_keeps_its_estimate(grids, monkeypatch):
    grid = grids[0]
    tracker = Tracker(grid.rig, grid.markers)
    frames = _stream_frames(grid, 20)
    for left, right, t, _ in frames[:12]:
        assert tracker.process(left, right, t).ok
    refiner = tracker.refiner
    assert refiner.scheduler.pending, "the refinement should be collecting a chunk"
    before = (refiner.estimator.estimate.R.copy(), refiner.estimator.estimate.T.copy(), refiner.estimator.updates)

    def singular(self, chunk, prior):
        raise np.linalg.LinAlgError("Singular matrix")

    # Raised inside the estimator's solve, run from RigRefiner.add_frame (rig_refine.py) through the
    # scheduler: the tracker must see where it came from.
    monkeypatch.setattr(RigEstimator, "solve", singular)
    results = [tracker.process(left, right, t) for left, right, t, _ in frames[12:]]
    failed = [r for r in results if not r.ok]
    assert len(failed) == 1 and failed[0].reason == "internal error: LinAlgError: Singular matrix"
    assert tracker.internal_errors == 1 and tracker.refiner is refiner
    assert len(refiner.scheduler.pending) < refiner.estimator.config.chunk_frames      # dropped and collecting anew
    estimate = refiner.estimator.estimate
    assert np.array_equal(estimate.R, before[0]) and np.array_equal(estimate.T, before[1])
    assert refiner.estimator.updates == before[2]
    for r, (_, _, _, i) in zip(results, frames[12:]):
        if r.ok:
            pos, ang = _errors(r, grid, i)
            assert pos < 0.5 and ang < 0.3


@pytest.mark.slow
@pytest.mark.parametrize("exc", [KeyboardInterrupt, SystemExit])
def test_interrupts_are_not_isolated(grids, monkeypatch, exc):
    grid = grids[0]

    def interrupted(self, *args, **kwargs):
        raise exc()

    monkeypatch.setattr(PoseFitter, "estimate", interrupted)
    tracker = Tracker(grid.rig, grid.markers)
    left, right, t, _ = _stream_frames(grid, 1)[0]
    with pytest.raises(exc):
        tracker.process(left, right, t)
    assert tracker.internal_errors == 0


# ---------------------------------------------------------------------------
# times the motion model cannot support
# ---------------------------------------------------------------------------

SWEEP = Path(__file__).parent / "data" / "sweep12"


@pytest.mark.slow
@pytest.mark.parametrize("refine", [False, True])
@pytest.mark.parametrize("offset_s", [-0.033, -0.016, 0.004, 0.016, 0.033])
def test_frames_a_ms_apart_never_give_a_pose_their_times_cannot_support(refine, offset_s):
    # The issue's case: sweep12's frames (0.1 s apart, the head turning ~15° between them) stamped
    # 1 ms apart, with the right image's time given. A velocity over 1 ms extrapolated over the
    # offset put the right view's model hundreds of mm away, and the rig's offset uncertainty times
    # that velocity widened the checks enough to pass it: 364-490 mm and 58-68° off. A velocity
    # over such a base is not a head's (thousands of °/s): no compensation, no pose.
    ds = io.Dataset(SWEEP)
    tracker = Tracker(ds.rig, ds.markers, TrackerConfig(rig_refine=RigRefineConfig(enabled=refine)))
    for k, f in enumerate(ds):
        t = 0.001 * k
        r = tracker.process(f.left, f.right, t, t + offset_s)
        if r.ok:
            p1, axes = ds.truth[f.index]
            pos = float(np.linalg.norm(r.position_mm - p1))
            ang = float(np.degrees(np.arccos(np.clip(r.axes[2] @ axes[2], -1, 1))))
            assert pos <= MAX_POS_MM and ang <= MAX_V_DEG, (k, pos, ang)
    assert tracker.internal_errors == 0


@pytest.mark.slow
def test_frames_a_ms_apart_keep_their_poses_when_the_cameras_are_synchronous():
    # The same stream without an offset: nothing is extrapolated, every stereo pair is a pose,
    # as accurate as with true times (sweep12 with its own times: ~0.05 mm, ~0.05°).
    ds = io.Dataset(SWEEP)
    tracker = Tracker(ds.rig, ds.markers)
    for k, f in enumerate(ds):
        r = tracker.process(f.left, f.right, 0.001 * k)
        p1, axes = ds.truth[f.index]
        assert r.ok, (k, r.reason)
        assert np.linalg.norm(r.position_mm - p1) < 0.5
        assert np.degrees(np.arccos(np.clip(r.axes[2] @ axes[2], -1, 1))) < 0.3


@pytest.mark.slow
def test_a_jump_in_time_resets_the_motion_and_says_so(grids):
    grid = grids[1]
    tracker = Tracker(grid.rig, grid.markers)
    frames = _stream_frames(grid, 16)
    times = [t for _, _, t, _ in frames]
    times[6:] = [t - 0.5 for t in times[6:]]          # back 0.5 s at frame 6
    times[11:] = [t + 3.0 for t in times[11:]]        # ahead 3 s at frame 11
    results = []
    for (left, right, _, i), t in zip(frames, times):
        r = tracker.process(left, right, t)
        results.append(r)
        pos, ang = _errors(r, grid, i)
        assert r.ok and pos < 0.5 and ang < 0.3
    for k, r in enumerate(results):
        jumped = [n for n in r.notes if "motion state reset" in n]
        assert bool(jumped) == (k in (6, 11)), (k, r.notes)
        if jumped:
            assert r.mode == "acquire" and r.record_extras()["notes"] == r.notes
    assert "went back 467 ms" in results[6].notes[0] and "jumped 3.0 s ahead" in results[11].notes[0]


@pytest.mark.slow
def test_repeated_times_divide_nothing_by_zero(grids):
    grid = grids[1]
    tracker = Tracker(grid.rig, grid.markers, TrackerConfig())
    frames = _stream_frames(grid, 14)
    with np.errstate(divide="raise", invalid="raise"):      # a 0/0 or x/0 would raise (and be counted)
        for k, (left, right, t, i) in enumerate(frames):
            t = frames[k - 1][2] if k % 3 == 2 else t       # every third frame repeats the time before
            r = tracker.process(left, right, t, t + 0.008)    # and a declared 8 ms offset to bridge
            assert tracker.internal_errors == 0, tracker.first_internal_traceback
            if r.ok:
                # A repeated time hides a frame of motion from the velocity: the 8 ms offset's
                # compensation may miss up to a quarter of a frame's motion on this 140°/s sweep
                # (~1°, a few mm), against ~0.2 mm, 0.1° with true times.
                pos, ang = _errors(r, grid, i)
                assert pos < 4.0 and ang < 1.0, (k, pos, ang)
            if k % 3 == 2:
                assert any("repeats the previous frame's" in n for n in r.notes)
    velocity = tracker.parts.motion.history.velocity()
    assert velocity is not None and np.isfinite(np.concatenate(velocity)).all()


def test_a_velocity_spans_at_least_the_minimum_base():
    # Poses at 0, 33, 34 ms (the last a timestamp glitch): the velocity is over the 34 ms from the
    # first, not the 1 ms from the second; a head turning 30°/s gives 30°/s, not the glitch's 1000s.
    history = PoseHistory()
    turn = np.radians(30.0)                       # rad/s about the vertical
    for t in (0.0, 0.033, 0.034):
        R = cv2.Rodrigues(np.array([0.0, turn * t, 0.0]))[0]
        R = R if t != 0.034 else cv2.Rodrigues(np.array([0.0, turn * 0.066, 0.0]))[0]   # a frame late
        history.add(t, R, np.zeros(3), 0)
    omega, _ = history.velocity()
    assert np.degrees(np.linalg.norm(omega)) == pytest.approx(30.0 * 0.066 / 0.034, rel=1e-6)
