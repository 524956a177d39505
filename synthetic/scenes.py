"""Scene presets: head trajectories, frame times and render options.

A :class:`Scene` bundles a rig + screen (:class:`~synthetic.setups.Setup`),
a marker model, a pose as a function of time and the render options.  Heads
are placed in the monitor frame M (see :mod:`synthetic.setups`: origin at
the screen centre, x_M toward the user's left, y_M down, z_M toward the user,
mm) and look at a point on the screen (V toward the screen), then turned by
yaw / pitch / roll about their own axes (see
:func:`synthetic.conventions.head_rotation`).  Rotations turn the head about a
neck pivot 80 mm below and 90 mm behind the bridge, so P1 moves with them as
on a real head.

Use ``make_scene(name, n_frames=..., seed=...)`` or ``PRESETS[name](...)``;
``list(PRESETS)`` gives the names.
"""
from __future__ import annotations

from dataclasses import replace, dataclass, field
from typing import Callable, Dict, Optional, Sequence, Tuple

import numpy as np

from .conventions import DEFAULT_DIAMETER_MM, DEFAULT_MARKERS_MM, head_rotation, model_axes, viewing_axes
from .render import Lamp, RenderOptions, expected_peak_dn, project_points, rig_cameras
from .setups import NOMINAL_HEAD_M, Setup, default_setup, wide_hd_setup

__all__ = [
    "Scene",
    "CURVED_MARKERS_MM",
    "CURVED_DIAMETER_MM",
    "NECK_PIVOT_HEAD_MM",
    "make_pose_fn",
    "make_scene",
    "preset_name",
    "PRESETS",
    "markers_visible",
]

#: Marker model of the ``custom_model`` preset: a curved, asymmetric frame
#: (P3, P4 8 mm behind the P0-P1-P2 line), rows P0..P4 in G, mm.
CURVED_MARKERS_MM = np.array(
    [
        [70.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [-60.0, 0.0, 0.0],
        [36.0, -32.0, -8.0],
        [-44.0, -27.0, -8.0],
    ]
)
CURVED_DIAMETER_MM = 7.0

#: Neck pivot in the head frame (x toward P0, y up, z = V), mm.
NECK_PIVOT_HEAD_MM = np.array([0.0, -80.0, -90.0])

PoseFn = Callable[[float], Tuple[np.ndarray, np.ndarray]]


@dataclass
class Scene:
    """A synthetic recording: what to render and when.

    Attributes
    ----------
    name : preset name.
    setup : rig + screen geometry.
    model_points_mm : (5, 3) marker model P0..P4 in G, mm.
    diameter_mm : marker diameter, mm.
    pose_fn : ``pose_fn(t) -> (R_world_from_G (3, 3), p1_world_mm (3,))``.
    times : (N,) mid-exposure times of the left images, s.
    options : render options (time offset, motion blur, distractors...).
    description : one line for people.
    frame_options : optional list of per-frame render options.
    calibrated_setup : the rig ``rig.yaml`` describes when it is not the
        one the images are rendered with (a stale calibration,
        :mod:`synthetic.imperfect`); None: the true rig.
    declare_time_offset : whether ``times.csv`` states the right image's
        time (``t_right``); unsynchronized webcams do not.
    frame_setups : optional list of per-frame true rigs (a camera bumped
        during the recording) overriding ``setup`` for rendering.
    stamps : optional (N,) times written as ``t`` in ``times.csv`` when
        they are not the exposure times ``times`` (a host's timestamps, with
        jitter), s; truth.csv refers to them (the contract: truth at t).
    stamps_right : optional (N,) times written as ``t_right`` (when the
        offset is declared), s; None: ``t + right_time_offset_s``.
    repeats : optional {frame: earlier frame}: frames whose image pair is
        the earlier frame's again (a driver delivering a buffer twice).
    webcam_truth : optional JSON-able dict written as ``webcam_truth.json``
        (:mod:`synthetic.imperfect`: readout, per-frame offsets, exposure
        steps, dropped and repeated frames), kept aside like truth.csv.
    """

    name: str
    setup: Setup
    model_points_mm: np.ndarray
    diameter_mm: float
    pose_fn: PoseFn
    times: np.ndarray
    options: RenderOptions = field(default_factory=RenderOptions)
    description: str = ""
    frame_options: Optional[list] = None    # per-frame RenderOptions overriding ``options``
    calibrated_setup: Optional[Setup] = None
    declare_time_offset: bool = True
    frame_setups: Optional[list] = None
    stamps: Optional[np.ndarray] = None
    stamps_right: Optional[np.ndarray] = None
    repeats: Optional[Dict[int, int]] = None
    webcam_truth: Optional[dict] = None

    def setup_for(self, frame: int) -> Setup:
        """The true rig of one frame (the cameras may be bumped during a recording)."""
        return self.frame_setups[frame] if self.frame_setups is not None else self.setup

    def options_for(self, frame: int) -> RenderOptions:
        """Render options of one frame (distractors may change per frame)."""
        return self.frame_options[frame] if self.frame_options is not None else self.options

    def stamp(self, frame: int) -> float:
        """The time ``times.csv`` lists for a frame (``t``; truth.csv refers to it), s."""
        return float(self.stamps[frame] if self.stamps is not None else self.times[frame])

    @property
    def n_frames(self) -> int:
        return int(len(self.times))

    def marker_positions(self, t: float) -> np.ndarray:
        """World positions (5, 3) mm of P0..P4 at time t."""
        R, p = self.pose_fn(t)
        return np.asarray(self.model_points_mm, float) @ np.asarray(R, float).T + np.asarray(p, float)

    def truth(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """Contract truth at time t: (position of P1 (3,) mm, axes (3, 3) rows Ξ, Ψ, V)."""
        R, p = self.pose_fn(t)
        pts = np.asarray(self.model_points_mm, float) @ np.asarray(R, float).T + np.asarray(p, float)
        return pts[1].copy(), viewing_axes(pts, self.model_points_mm, R)


def make_pose_fn(
    setup: Setup,
    position_m: Callable[[float], Sequence[float]],
    target_m: Callable[[float], Sequence[float]],
    ypr_deg: Callable[[float], Sequence[float]],
    model_points_mm: np.ndarray = DEFAULT_MARKERS_MM,
    pivot_head_mm: Optional[np.ndarray] = NECK_PIVOT_HEAD_MM,
) -> PoseFn:
    """Pose function from a head path given in the monitor frame.

    Parameters
    ----------
    setup : provides the monitor frame M in the world.
    position_m : t -> (3,) nominal P1 position in M, mm (the position it
        has with yaw = pitch = roll = 0).
    target_m : t -> (3,) point in M (mm, usually on the screen z_M = 0) the
        head's V points to before yaw / pitch / roll.
    ypr_deg : t -> (yaw, pitch, roll) in degrees, applied about the head axes
        (see :func:`synthetic.conventions.head_rotation`).
    model_points_mm : the marker model; for a curved model the head axes
        (Ξ, Ψ, V), not G, are what the rotation sets.
    pivot_head_mm : rotation centre in the head frame (mm) or None to rotate
        about P1.

    Returns
    -------
    pose_fn(t) -> (R_world_from_G (3, 3), p1_world_mm (3,)).
    """
    A = model_axes(model_points_mm)  # head coordinates from G coordinates
    up_w = setup.dir_m_to_world([0.0, -1.0, 0.0])

    def pose_fn(t: float):
        p_m = np.asarray(position_m(t), float)
        fwd_w = setup.dir_m_to_world(np.asarray(target_m(t), float) - p_m)
        yaw, pitch, roll = ypr_deg(t)
        R0 = head_rotation(0.0, 0.0, 0.0, facing=fwd_w, up=up_w)
        R = head_rotation(yaw, pitch, roll, facing=R0)
        p_w = setup.m_to_world(p_m)
        if pivot_head_mm is not None:
            pv = np.asarray(pivot_head_mm, float)
            p_w = p_w + R0 @ pv - R @ pv
        return R @ A, p_w

    return pose_fn


def markers_visible(setup: Setup, model_points_mm: np.ndarray, diameter_mm: float, R: np.ndarray,
                    p: np.ndarray, margin_px: float = 12.0, min_cos: float = 0.25,
                    min_peak_dn: float = 0.0, options: Optional[RenderOptions] = None) -> bool:
    """True when all five markers face both cameras (cos of the entrance
    angle ≥ ``min_cos``), project at least ``margin_px`` inside both images
    and, when ``min_peak_dn`` > 0, have an expected blob peak
    (:func:`synthetic.render.expected_peak_dn`) of at least ``min_peak_dn``
    DN above the background.

    ``R`` (3, 3) is R_world_from_G and ``p`` (3,) the P1 position in world, mm.
    """
    pts = np.asarray(model_points_mm, float) @ R.T + p
    w, h = setup.image_size
    opts = options or RenderOptions()
    for cam in rig_cameras(setup):
        if min_peak_dn > 0 and any(expected_peak_dn(cam, q, R[:, 2], diameter_mm, opts) < min_peak_dn
                                   for q in pts):
            return False
        pc = cam.to_cam(pts)
        if np.any(pc[:, 2] < 200.0):
            return False
        n = cam.R @ R[:, 2]
        cos = -(pc @ n) / np.linalg.norm(pc, axis=1)
        if np.any(cos < min_cos):
            return False
        if np.any(np.hypot(pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]) > 0.9 * cam.r_max):
            return False
        uv = project_points(cam, pts)
        if np.any(uv < margin_px) or np.any(uv[:, 0] > w - 1 - margin_px) or np.any(uv[:, 1] > h - 1 - margin_px):
            return False
    return True


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------

def _times(n: int, fps: float) -> np.ndarray:
    return np.arange(int(n), dtype=np.float64) / float(fps)


def _const(v):
    v = np.asarray(v, float)
    return lambda t: v


def _screen_centre(t):
    return np.zeros(3)


def _cycle(n: int, fps: float) -> float:
    """Duration of n frames (one full sweep period), s."""
    return max(int(n), 2) / float(fps)


def _ease_turns(t: float, amp: float, turn_s: float, hold_s: float) -> float:
    """Alternating turns between -amp and +amp (cosine easing, ``turn_s`` long,
    then ``hold_s`` still).  Peak rate ``amp * pi / turn_s`` (deg/s)."""
    period = 2.0 * (turn_s + hold_s)
    ph = t % period
    half = turn_s + hold_s
    sign = 1.0 if ph < half else -1.0
    ph = ph % half
    if ph < turn_s:
        return -sign * amp * np.cos(np.pi * ph / turn_s)
    return sign * amp


def _scene(name, setup, pose_fn, times, options, description, model=DEFAULT_MARKERS_MM,
           diameter=DEFAULT_DIAMETER_MM) -> Scene:
    return Scene(name=name, setup=setup, model_points_mm=np.array(model, float), diameter_mm=float(diameter),
                 pose_fn=pose_fn, times=np.asarray(times, float), options=options, description=description)


def _head_at(z_mm: float, x_mm: float = 0.0, y_mm: float = NOMINAL_HEAD_M[1]) -> np.ndarray:
    return np.array([x_mm, y_mm, z_mm], float)


# ----------------------------------------------------------------------------
# presets
# ----------------------------------------------------------------------------

def static(n_frames: int = 30, seed: int = 0, distance_mm: float = 600.0, fps: float = 30.0,
           setup: Optional[Setup] = None, diameter_mm: float = DEFAULT_DIAMETER_MM) -> Scene:
    """A still head at ``distance_mm`` from the screen, looking at its centre (markers ``diameter_mm`` wide)."""
    s = setup or default_setup()
    pf = make_pose_fn(s, _const(_head_at(distance_mm)), _screen_centre, _const((0.0, 0.0, 0.0)))
    return _scene("static", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"still head at {distance_mm:.0f} mm looking at the screen centre", diameter=diameter_mm)


def looking_around(n_frames: int = 150, seed: int = 0, fps: float = 30.0) -> Scene:
    """The built-in sequence: a user at 55-75 cm reading around the screen.

    The point looked at wanders over the screen on a Lissajous path (5 s
    period), the head sways ±60 mm sideways and ±10 cm in depth, with a
    little roll: ordinary desk use, the tracker's everyday case.
    """
    s = default_setup()
    T = 5.0
    half_w, half_h = 265.7 * 0.8, 149.45 * 0.8

    def position(t):
        return np.array([60.0 * np.sin(2 * np.pi * t / (1.7 * T)), NOMINAL_HEAD_M[1] + 20.0 * np.sin(2 * np.pi * t / T),
                         650.0 + 100.0 * np.sin(2 * np.pi * t / (2.3 * T))])

    def target(t):
        return np.array([half_w * np.sin(2 * np.pi * t / T), half_h * np.sin(4 * np.pi * t / T + 0.7), 0.0])

    pf = make_pose_fn(s, position, target, lambda t: (0.0, 0.0, 6.0 * np.sin(2 * np.pi * t / (1.3 * T))))
    return _scene("looking_around", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  "a user at 55-75 cm looking around the screen")


def yaw_sweep(n_frames: int = 60, seed: int = 0, amplitude_deg: float = 45.0, fps: float = 30.0) -> Scene:
    """One full sinusoidal yaw cycle of ±``amplitude_deg`` at the nominal head position."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre,
                      lambda t: (amplitude_deg * np.sin(2 * np.pi * t / T), 0.0, 0.0))
    return _scene("yaw_sweep", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"yaw sweep ±{amplitude_deg:g}° at 65 cm")


def pitch_sweep(n_frames: int = 60, seed: int = 0, amplitude_deg: float = 30.0, fps: float = 30.0) -> Scene:
    """One full sinusoidal pitch cycle of ±``amplitude_deg``."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre,
                      lambda t: (0.0, amplitude_deg * np.sin(2 * np.pi * t / T), 0.0))
    return _scene("pitch_sweep", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"pitch sweep ±{amplitude_deg:g}° at 65 cm")


def neck_turns(n_frames: int = 48, seed: int = 0, yaw_deg: float = 30.0, pitch_deg: float = 15.0,
               fps: float = 30.0) -> Scene:
    """A head turning about its neck (``NECK_PIVOT_HEAD_MM``): left-right ±``yaw_deg``, then up-down ±``pitch_deg``.

    The first half of the frames is one sinusoidal yaw cycle, the second one
    pitch cycle, at the nominal head position: what a user does when asked
    to show the tracker where the head's pivot is (``headplod pivot``). The
    pivot stays still in the world; P1 swings about it.
    """
    s = default_setup()
    n = max(int(n_frames), 2)
    half_s = (n / 2.0) / float(fps)

    def ypr(t):
        if t < half_s:
            return (yaw_deg * np.sin(2 * np.pi * t / half_s), 0.0, 0.0)
        return (0.0, pitch_deg * np.sin(2 * np.pi * (t - half_s) / half_s), 0.0)

    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre, ypr)
    return _scene("neck_turns", s, pf, _times(n, fps), RenderOptions(ambient_seed=seed),
                  f"head turns about the neck: yaw ±{yaw_deg:g}°, then pitch ±{pitch_deg:g}°, at 65 cm")


def roll_sweep(n_frames: int = 60, seed: int = 0, amplitude_deg: float = 30.0, fps: float = 30.0) -> Scene:
    """One full sinusoidal roll cycle of ±``amplitude_deg``."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre,
                      lambda t: (0.0, 0.0, amplitude_deg * np.sin(2 * np.pi * t / T)))
    return _scene("roll_sweep", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"roll sweep ±{amplitude_deg:g}° at 65 cm")


def distance_sweep(n_frames: int = 60, seed: int = 0, near_mm: float = 400.0, far_mm: float = 1500.0,
                   fps: float = 30.0) -> Scene:
    """Head moving from ``near_mm`` to ``far_mm`` from the screen and back, small yaw."""
    s = default_setup()
    T = _cycle(n_frames, fps)

    def pos(t):
        z = near_mm + (far_mm - near_mm) * 0.5 * (1 - np.cos(2 * np.pi * t / T))
        return _head_at(z)

    pf = make_pose_fn(s, pos, _screen_centre, lambda t: (10.0 * np.sin(4 * np.pi * t / T), 0.0, 0.0))
    return _scene("distance_sweep", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"distance {near_mm:.0f}-{far_mm:.0f} mm and back")


def fast_motion(n_frames: int = 90, seed: int = 0, fps: float = 60.0, exposure_s: float = 0.008,
                offset_s: float = 0.004) -> Scene:
    """Fast head: lateral sway peaking at 1 m/s and yaw/pitch turn bursts up to
    200°/s, with motion blur (``exposure_s``, 8 sub-exposures) and the right
    image ``offset_s`` after the left one."""
    s = default_setup()
    amp_x = 150.0
    w = 1000.0 / amp_x  # rad/s: peak lateral speed 1000 mm/s

    def pos(t):
        return np.array([amp_x * np.sin(w * t), NOMINAL_HEAD_M[1] + 20 * np.sin(0.7 * w * t), 650.0])

    def ypr(t):
        yaw = _ease_turns(t, 30.0, 30.0 * np.pi / 200.0, 0.25)  # 200 deg/s peak
        pitch = _ease_turns(t + 0.2, 12.0, 12.0 * np.pi / 120.0, 0.4)
        return yaw, pitch, 5.0 * np.sin(3.0 * t)

    pf = make_pose_fn(s, pos, _screen_centre, ypr)
    opts = RenderOptions(ambient_seed=seed, exposure_s=exposure_s, motion_samples=8, right_time_offset_s=offset_s)
    return _scene("fast_motion", s, pf, _times(n_frames, fps), opts,
                  "1 m/s lateral sway, 200°/s yaw bursts, 8 ms motion blur, right image 4 ms late")


def random_poses(n_frames: int = 100, seed: int = 0, fps: float = 30.0, setup: Optional[Setup] = None,
                 yaw_deg: float = 45.0, pitch_deg: float = 30.0, roll_deg: float = 30.0,
                 z_range_mm: Tuple[float, float] = (400.0, 1500.0), min_peak_dn: float = 15.0) -> Scene:
    """Independent random poses (one per frame): P1 anywhere in the region in
    front of the screen that both cameras see (distance 40-150 cm), looking
    at a random point of the screen, turned by uniform yaw ±45°, pitch ±30°,
    roll ±30°.  Poses are redrawn when a marker leaves an image (12 px
    margin), faces a camera at more than ≈ 75°, or its expected blob peak is
    below ``min_peak_dn`` DN above the background (far and tilted at once;
    0 disables this test).  ``pose_fn`` is piecewise constant (nearest
    frame)."""
    s = setup or default_setup()
    rng = np.random.default_rng([int(seed), 4242])
    model = DEFAULT_MARKERS_MM
    sw, sh = 265.7, 149.45
    poses = []
    while len(poses) < n_frames:
        z = rng.uniform(*z_range_mm)
        p_m = np.array([rng.uniform(-0.55, 0.55) * z, NOMINAL_HEAD_M[1] + rng.uniform(-0.3, 0.3) * z, z])
        tgt = np.array([rng.uniform(-sw, sw), rng.uniform(-sh, sh), 0.0])
        ypr = (rng.uniform(-yaw_deg, yaw_deg), rng.uniform(-pitch_deg, pitch_deg), rng.uniform(-roll_deg, roll_deg))
        pf = make_pose_fn(s, _const(p_m), _const(tgt), _const(ypr), model)
        R, p = pf(0.0)
        if markers_visible(s, model, DEFAULT_DIAMETER_MM, R, p, min_peak_dn=min_peak_dn):
            poses.append((R, p))
    Rs = np.array([q[0] for q in poses])
    ps = np.array([q[1] for q in poses])

    def pose_fn(t):
        i = int(np.clip(np.rint(t * fps), 0, len(ps) - 1))
        return Rs[i], ps[i]

    return _scene("random", s, pose_fn, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  "independent random poses over the shared field of view")


def extreme(n_frames: int = 40, seed: int = 0, fps: float = 30.0, offset_mm: float = 250.0) -> Scene:
    """Yaw ±60° combined with roll ±35° from looking straight at the screen
    (first half +, second half −), with a slow ±3° wobble.

    At the nominal position the camera the face turns away from would see
    the disks at ≈ 85°, edge-on: no tracker sees them there. So the head sits
    ``offset_mm`` to the side it turns away from (first half: toward the
    user's right, x_M = −offset), where the two cameras see the markers at
    ≈ 64° and ≈ 22°: foreshortened to ellipses and dim in one view, but there.
    """
    s = default_setup()
    T = _cycle(n_frames, fps)

    def side(t):
        return 1.0 if t < T / 2 else -1.0

    def position(t):
        return np.array([-side(t) * offset_mm, NOMINAL_HEAD_M[1], 700.0])

    def ypr(t):
        wob = 3.0 * np.sin(2 * np.pi * 3 * t / T)
        return side(t) * 60.0 + wob, wob, side(t) * 35.0 - wob

    pf = make_pose_fn(s, position, lambda t: position(t) * [1.0, 1.0, 0.0], ypr)
    return _scene("extreme", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"yaw ±60° with roll ±35° at 70 cm, head {offset_mm:.0f} mm to the side")


def random_mixed(n_frames: int = 200, seed: int = 0, fps: float = 30.0, glint_fraction: float = 0.3,
                 occlusion_fraction: float = 0.2, lamp_fraction: float = 0.15) -> Scene:
    """Random poses (as :func:`random_poses`) with distractors mixed in per
    frame: 1-4 glints in ``glint_fraction`` of the frames, one marker hidden
    in one view in ``occlusion_fraction``, an IR lamp in ``lamp_fraction``;
    drawn independently per frame from ``seed``."""
    base = random_poses(n_frames=n_frames, seed=seed, fps=fps)
    s = base.setup
    rng = np.random.default_rng([int(seed), 777])
    lamp = Lamp(tuple(s.m_to_world([-80.0, -420.0, 2200.0])), radius_mm=45.0, peak_dn=420.0)
    per_frame = []
    for _ in range(n_frames):
        kw = {}
        if rng.random() < glint_fraction:
            kw["glints"] = (1, 4)
        if rng.random() < occlusion_fraction:
            kw["occluded"] = frozenset({(int(rng.integers(0, 2)), int(rng.integers(0, 5)))})
        if rng.random() < lamp_fraction:
            kw["lamps"] = (lamp,)
        per_frame.append(base.options.replace(**kw))
    scene = replace(base, name="random_mixed",
                    description="random poses with glints, a hidden marker and lamps mixed in per frame")
    scene.frame_options = per_frame
    return scene


def dim_ir(n_frames: int = 40, seed: int = 0, fps: float = 30.0, brightness_scale: float = 0.44) -> Scene:
    """Weak IR illumination (``brightness_scale`` 0.44): marker peaks
    ≈ 55-105 DN including the ≈ 15 DN background, for a head swaying ±8° at
    64-68 cm."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, lambda t: _head_at(660.0 + 20.0 * np.sin(2 * np.pi * t / T)), _screen_centre,
                      lambda t: (8.0 * np.sin(2 * np.pi * t / T), 5.0 * np.sin(4 * np.pi * t / T), 0.0))
    opts = RenderOptions(ambient_seed=seed, brightness_scale=brightness_scale)
    return _scene("dim_ir", s, pf, _times(n_frames, fps), opts, "dim IR: marker peaks 50-110 DN")


def glints_lamp(n_frames: int = 40, seed: int = 0, fps: float = 30.0) -> Scene:
    """Yaw sweep ±25° with 1-4 specular glints per image near the glasses and
    two IR lamps in the room (one behind the user seen by both cameras, one
    on the user's right seen by the right camera only)."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre,
                      lambda t: (25.0 * np.sin(2 * np.pi * t / T), 5.0 * np.sin(4 * np.pi * t / T), 0.0))
    lamps = (
        Lamp(tuple(s.m_to_world([-80.0, -420.0, 2200.0])), radius_mm=45.0, peak_dn=420.0),
        Lamp(tuple(s.m_to_world([-700.0, 150.0, 1300.0])), radius_mm=25.0, peak_dn=300.0),
    )
    opts = RenderOptions(ambient_seed=seed, glints=(1, 4), lamps=lamps)
    return _scene("glints_lamp", s, pf, _times(n_frames, fps), opts, "specular glints and IR lamps")


def clutter(n_frames: int = 60, seed: int = 0, fps: float = 30.0, blobs: int = 20, glints: int = 0) -> Scene:
    """The built-in motion (:func:`looking_around`) in a cluttered room: ``blobs`` blobs per image in all.

    The five markers and ``blobs - 5`` shiny things as 3D points both cameras see (a watch, a lamp's
    chrome, a reflective strip behind the user, the spectacles' hinges; :mod:`synthetic.clutter` says
    where and how bright, and why), each its own blob in every frame; plus ``glints`` independent specular
    glints per image near the glasses (``RenderOptions.glints``; they add to ``blobs``).  ``blobs`` 5 is
    the markers alone.  The clutter is placed from ``seed``; a larger ``blobs`` adds objects to the
    smaller one's.
    """
    from .clutter import place_reflectors

    if blobs < 5:
        raise ValueError(f"blobs counts the five markers: at least 5, got {blobs}")
    base = looking_around(n_frames=n_frames, seed=seed, fps=fps)
    refs = place_reflectors(base.setup, base.model_points_mm, base.diameter_mm, base.pose_fn, base.times,
                            int(blobs) - 5, seed=seed, d_ref_mm=base.options.d_ref_mm)
    opts = base.options.replace(reflectors=refs, glints=(int(glints), int(glints)))
    extra = f" and {glints} glints" if glints else ""
    return replace(base, name="clutter", options=opts,
                   description=f"looking around with {blobs} blobs per image (markers and shiny things){extra}")


def occlusion(n_frames: int = 40, seed: int = 0, fps: float = 30.0, hidden=((1, 3),)) -> Scene:
    """Slow yaw sway with a marker hidden in one view (default P3 in the right
    image, e.g. behind a hand or the frame's hinge)."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(NOMINAL_HEAD_M), _screen_centre,
                      lambda t: (20.0 * np.sin(2 * np.pi * t / T), 0.0, 0.0))
    opts = RenderOptions(ambient_seed=seed, occluded=frozenset(tuple(h) for h in hidden))
    return _scene("occlusion", s, pf, _times(n_frames, fps), opts,
                  "marker(s) hidden in one view: " + ", ".join(f"cam {c} P{m}" for c, m in hidden))


def far(n_frames: int = 40, seed: int = 0, fps: float = 30.0, distance_mm: float = 1200.0) -> Scene:
    """Head at ``distance_mm`` (default 120 cm) with a gentle ±10° yaw sway."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    pf = make_pose_fn(s, _const(_head_at(distance_mm)), _screen_centre,
                      lambda t: (10.0 * np.sin(2 * np.pi * t / T), 4.0 * np.sin(4 * np.pi * t / T), 0.0))
    return _scene("far", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  f"head at {distance_mm:.0f} mm")


def wide_hd(n_frames: int = 60, seed: int = 0, fps: float = 30.0) -> Scene:
    """The 1280x720 strongly distorted wide-angle rig; the head wanders over
    x_M ±250 mm and 45-130 cm with yaw ±35°, pitch ±15°, so markers reach the
    distorted image periphery."""
    s = wide_hd_setup()
    T = _cycle(n_frames, fps)

    def pos(t):
        ph = 2 * np.pi * t / T
        return np.array([250.0 * np.sin(ph), NOMINAL_HEAD_M[1] + 60.0 * np.sin(2 * ph), 875.0 - 425.0 * np.cos(ph)])

    pf = make_pose_fn(s, pos, _screen_centre,
                      lambda t: (35.0 * np.sin(2 * np.pi * 2 * t / T), 15.0 * np.sin(2 * np.pi * 3 * t / T), 0.0))
    return _scene("wide_hd", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  "1280x720 ≈100° HFOV rig with strong distortion")


def custom_model(n_frames: int = 60, seed: int = 0, fps: float = 30.0) -> Scene:
    """A curved, asymmetric marker frame (:data:`CURVED_MARKERS_MM`, 7 mm
    disks; written as markers.yaml) under yaw ±35° and pitch ±15°."""
    s = default_setup()
    T = _cycle(n_frames, fps)
    model = CURVED_MARKERS_MM
    pf = make_pose_fn(s, lambda t: _head_at(650.0 + 100.0 * np.sin(2 * np.pi * t / T), 40.0 * np.sin(4 * np.pi * t / T)),
                      _screen_centre,
                      lambda t: (35.0 * np.sin(2 * np.pi * t / T), 15.0 * np.sin(4 * np.pi * t / T), 0.0),
                      model_points_mm=model)
    return _scene("custom_model", s, pf, _times(n_frames, fps), RenderOptions(ambient_seed=seed),
                  "curved asymmetric frame (P3, P4 at z = -8 mm), 7 mm markers", model=model,
                  diameter=CURVED_DIAMETER_MM)


#: name -> preset function ``f(n_frames=..., seed=..., **kw) -> Scene``.
def imperfect_rig(n_frames: Optional[int] = None, seed: int = 0, **faults) -> Scene:
    """A preset's motion seen by a rig that ``rig.yaml`` describes wrongly (:func:`synthetic.imperfect.imperfect_rig`)."""
    from .imperfect import imperfect_rig as make

    return make(n_frames=n_frames, seed=seed, **faults)


def ordinary_webcams(n_frames: Optional[int] = None, seed: int = 0, **changes) -> Scene:
    """Two ordinary USB webcams, everything at once (:func:`synthetic.imperfect.ordinary_webcams`)."""
    from .imperfect import ordinary_webcams as make

    return make(n_frames=n_frames, seed=seed, **changes)


PRESETS: Dict[str, Callable[..., Scene]] = {
    "looking_around": looking_around,
    "static": static,
    "yaw_sweep": yaw_sweep,
    "pitch_sweep": pitch_sweep,
    "roll_sweep": roll_sweep,
    "neck_turns": neck_turns,
    "distance_sweep": distance_sweep,
    "fast_motion": fast_motion,
    "random": random_poses,
    "extreme": extreme,
    "dim_ir": dim_ir,
    "glints_lamp": glints_lamp,
    "clutter": clutter,
    "occlusion": occlusion,
    "far": far,
    "wide_hd": wide_hd,
    "custom_model": custom_model,
    "random_mixed": random_mixed,
    "imperfect_rig": imperfect_rig,
    "ordinary_webcams": ordinary_webcams,
}


#: other accepted names
ALIASES: Dict[str, str] = {
    "random_poses": "random",
    "still": "static",
    "glints": "glints_lamp",
    "lamp": "glints_lamp",
    "occluded": "occlusion",
    "wide": "wide_hd",
    "custom": "custom_model",
    "curved": "custom_model",
    "webcams": "ordinary_webcams",
}


def preset_name(name: str) -> str:
    """The key of :data:`PRESETS` that ``name`` stands for (an alias, ``-`` for ``_``, any case).

    Raises
    ------
    KeyError
        For an unknown name; the message lists the presets.
    """
    key = name.replace("-", "_").lower()
    key = ALIASES.get(key, key)
    if key not in PRESETS:
        raise KeyError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return key


def make_scene(name: str, n_frames: Optional[int] = None, seed: int = 0, **kwargs) -> Scene:
    """Build a preset scene.

    Parameters
    ----------
    name : a key of :data:`PRESETS` or :data:`ALIASES` (``-`` and ``_``
        are interchangeable).
    n_frames : number of frames (preset default when None).
    seed : seeds the random parts of the scene (random poses, ambient
        pattern); the per-frame noise is seeded by ``write_dataset``.
    kwargs : preset-specific options (e.g. ``distance_mm`` for ``static``).
    """
    key = preset_name(name)
    if n_frames is not None:
        kwargs["n_frames"] = int(n_frames)
    return PRESETS[key](seed=seed, **kwargs)
