"""``headplod preview``: both cameras side by side, annotated, to set up the cameras and the light (issue 25).

    headplod preview [--source SPEC] [--calib rig.yaml] [--out DIR] [--frames N] [-q] [--threshold DN]
                     [--fps F] [--fourcc GREY|YUYV|MJPG] [--exposure E] [--gain G] [--markers FILE]

Each frame of the source (any ``--source SPEC``, as ``headplod track`` takes it)
becomes one picture: the left image on the left, the right image on the right,
and a panel of text under them. On each image:

- the pixels above the detection threshold, tinted red (the mask detection
  thresholded), and the threshold used, in DN, with the background and noise
  it came from;
- every blob: a circle around its centroid (radius from its area), its area in
  px; red when it is saturated, yellow when it is a glint;
- the markers P0..P4 as the tracker identified them (green: a verified pose;
  orange: identified, no pose, the panel says why);
- with a rig (``--calib``, or the dataset's own ``rig.yaml``): the epipolar
  line of every blob of the other image (magenta), from ``F`` of the rig
  through ``cv2.computeCorrespondEpilines`` on undistorted pixels, drawn
  through the lens distortion as a curve. A marker and its partner lie on each
  other's line when the rig is right.

The panel gives the frame, the frame rate measured from the frames' times, the
stereo skew ``|t_right - t|`` and advice derived from the measurements
(:class:`~headplod.live.preview_analysis.AdviceSettings` holds every threshold): saturated markers, no blobs,
too many blobs, too few, dim markers, a large skew, a rate below the one
requested.

Without a rig (cameras not calibrated yet) the threshold and the blobs are
still shown; identification needs the rig (the tracker picks the left/right
pair of labelings by the epipolar geometry), so the images say "no rig:
epipolar lines and identification after 'headplod calibrate'".

Detection and identification are the tracker's own: :class:`~headplod.tracking.tracker.Tracker`
(re-detecting every frame, the rig's online refinement off) and, without a
rig, :func:`~headplod.tracking.detect.detect_blobs` with the same parameters.

Where the pictures go: with ``--out DIR``, one PNG per frame,
``DIR/preview_0000.png``, ``preview_0001.png``, ... (each written under a
temporary name, then renamed), ``--frames N`` of them (default
:data:`HEADLESS_FRAMES`); without it a window (:mod:`.preview_window`, the
window library of the demo) showing the same pictures, until q or Esc, or
after ``--frames N`` frames; a replay's last picture stays up until then. Its
keys (:mod:`.preview_controls`) change the threshold, and on live cameras the
exposure and gain, while it runs; w writes them into the config file. Where
no window can be opened (no display), the command says to use ``--out DIR``.

Coordinates: image pixels (u, v), u right, v down, (0, 0) the *centre* of the
top-left pixel (docs/contract.md), which is also the convention of OpenCV's
projection functions and of its drawing functions at integer (and, with
``shift``, fixed-point) coordinates, so nothing is shifted by half a pixel. In
the composite picture the right image's pixel (u, v) is at (u + width, v).

Exit status: 0 success (a fault in one frame is that frame's picture, saying
so, and counted); 1 unreadable input (a source, rig or marker file that
cannot be read, a source that gives no frame) or an output that cannot be
written; 2 bad usage. Every option is checked and the source opened before
anything is written; nothing is ever written into the dataset folder being
read.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
from collections import deque
from pathlib import Path

import numpy as np

from .. import io
from ..argtypes import add_quiet_argument, frame_count, threshold_dn
from ..capture import open_source, source_kind, synthetic_preset, v4l2_devices
from ..capture.synthetic import ensure_dataset
from ..capture.command import DEFAULT_FPS, add_camera_settings
from ..io.files import OutputRefused, check_output
from ..progress import Progress
from ..tracking.detect import DetectionParams, detect_blobs, estimate_background
from .preview_analysis import (AdviceSettings, FrameAnalysis, ViewAnalysis, advise, box_counts, epipolar_curves,
                               threshold_mask)
from .preview_controls import Controls
from .preview_picture import NO_RIG_NOTE, composite_size, render
from .preview_window import PreviewWindow, WindowUnavailable, window_problem
from .track_checks import track_inputs

__all__ = ["add_preview_arguments", "run_preview", "Previewer", "HEADLESS_FRAMES", "OUT_NAME"]

#: Frames written with ``--out`` when ``--frames`` is not given.
HEADLESS_FRAMES = 10
#: The name of frame k's picture in ``--out DIR`` (k counts the frames shown, from 0).
OUT_NAME = "preview_{:04d}.png"
#: The names OUT_NAME gives, with the frame number as group 1 (pictures past 9999 take more digits).
_OUT_PATTERN = re.compile(r"preview_(\d{4,})\.png")
#: The pictures' names as a glob pattern (what --out DIR's check looks at).
OUT_GLOB = "preview_*.png"
#: Frame rate requested from live cameras when ``--fps`` is not given, Hz (as ``headplod track``).
LIVE_FPS = DEFAULT_FPS
#: Most epipolar lines drawn in an image (the other image's blobs beyond these, brightest first, are left out).
MAX_EPILINES = 16


class Previewer:
    """Analyses frames and draws their pictures, with the tracker's detection and identification.

    Parameters
    ----------
    rig : io.Rig or None
        Without one: blobs only (no epipolar lines, no identification).
    markers : io.MarkerModel, optional
        The glasses (default: the contract's model).
    detection : DetectionParams
        As the tracker's (its defaults: the adaptive threshold).
    settings : AdviceSettings
    requested_fps : float, optional
        The rate asked of live cameras, Hz (None for a replay: no rate advice).
    """

    def __init__(self, rig: io.Rig | None, markers: io.MarkerModel | None = None,
                 detection: DetectionParams = DetectionParams(), settings: AdviceSettings = AdviceSettings(),
                 requested_fps: float | None = None):
        self.rig, self.detection, self.settings, self.requested_fps = rig, detection, settings, requested_fps
        self.size = tuple(rig.image_size) if rig is not None else None
        self.markers = markers or io.default_marker_model()
        self.tracker = self._tracker()
        self._times = deque(maxlen=settings.rate_window_frames)
        #: The threshold the last frame's left image was detected at, DN (None before a frame).
        self.last_threshold_dn: float | None = None

    def _tracker(self):
        if self.rig is None:
            return None
        # Imported on use: the tracker pulls in scipy (`headplod --help` imports this module).
        from ..tracking.rig_refine_config import RigRefineConfig
        from ..tracking.tracker import Tracker, TrackerConfig

        config = TrackerConfig(detection=self.detection, track=False, rig_refine=RigRefineConfig(enabled=False))
        return Tracker(self.rig, self.markers, config, calibration_std=io.rig_calibration_std(self.rig))

    def set_threshold(self, threshold_dn: float | None) -> None:
        """Detect at ``threshold_dn`` DN (None: the adaptive threshold) from the next frame on."""
        self.detection = dataclasses.replace(self.detection, threshold_dn=threshold_dn)
        self.tracker = self._tracker()      # it re-detects every frame: nothing of the old one is lost

    # -- analysis ------------------------------------------------------------

    def analyse(self, frame: io.Frame, again: bool = False) -> FrameAnalysis:
        """What ``frame`` shows (raises on a fault; :meth:`picture` turns one into the frame's failure);
        ``again``: the frame was analysed before (a new threshold on a held picture): its time is not counted
        in the rate twice, and a new tracker sees it."""
        if again:                           # the tracker would take the frame for a repeated camera buffer
            self.tracker = self._tracker()
        base = dict(index=int(frame.index), t=frame.t, rig=self.rig is not None, warning=frame.warning)
        if frame.error is not None or frame.left is None or frame.right is None:
            return FrameAnalysis(views=None, size=self.size or (640, 480), error=frame.error or "no images", **base)
        images = (frame.left, frame.right)
        self.size = (images[0].shape[1], images[0].shape[0])
        skew = getattr(frame, "skew_ms", None)
        if skew is None:
            skew = 0.0 if frame.t_right is None else abs(frame.t_right - frame.t) * 1000.0
        if frame.t is not None and math.isfinite(frame.t) and not again:
            self._times.append(float(frame.t))
        rate = self._rate()

        result = None
        if self.tracker is not None:
            result = self.tracker.process(images[0], images[1], frame.t, frame.t_right)
        blobs = tuple(b if b is not None else detect_blobs(img, self.detection, background=estimate_background(img))
                      for b, img in zip(result.blobs if result is not None else (None, None), images))
        views = []
        self.last_threshold_dn = float(blobs[0].threshold_dn)
        for img, b in zip(images, blobs):
            clipped = box_counts(img >= self.settings.saturated_dn, b.bbox_px)
            views.append(ViewAnalysis(img, b, threshold_mask(img, b, self.detection), clipped,
                                      clipped >= self.settings.saturated_min_px))
        identified = result is not None and result.marker_blob is not None
        if identified:
            for cam in range(2):
                views[cam].markers_px = np.asarray(result.centers_px[cam], np.float64)
        if self.rig is not None and all(tuple(v.image.shape[::-1]) == tuple(self.rig.image_size) for v in views):
            for cam in range(2):
                other = views[1 - cam].blobs
                order = np.argsort(-other.flux_dn)[:MAX_EPILINES]
                views[cam].epilines = epipolar_curves(other.centers_px[order], self.rig, 1 - cam)[1]
        analysis = FrameAnalysis(views=tuple(views), size=self.size, skew_ms=skew, rate_hz=rate,
                                 identified=identified, pose_ok=bool(result is not None and result.ok),
                                 position_mm=None if result is None or not result.ok else result.position_mm,
                                 reason=None if result is None else result.reason, **base)
        analysis.advice = advise(views, skew, rate, len(self._times), self.requested_fps, self.settings)
        return analysis

    def _rate(self) -> float | None:
        """Frames per second over the recent frames' times, Hz; None before two frames or for times that
        do not advance."""
        if len(self._times) < 2:
            return None
        span = self._times[-1] - self._times[0]
        return (len(self._times) - 1) / span if span > 0 else None

    def picture(self, frame: io.Frame, again: bool = False) -> tuple[np.ndarray, FrameAnalysis]:
        """The frame's annotated picture (:func:`render`) and its analysis; never raises for the frame's
        own fault: an exception while analysing or drawing it gives a picture saying so (``error`` set)."""
        try:
            analysis = self.analyse(frame, again)
            return render(analysis), analysis
        except Exception as exc:            # noqa: BLE001 -- one frame's fault is that frame's failure
            from ..tracking.tracker import internal_error_reason

            analysis = FrameAnalysis(index=int(getattr(frame, "index", -1)), t=getattr(frame, "t", None),
                                     views=None, size=self.size or (640, 480), rig=self.rig is not None,
                                     error=internal_error_reason(exc))
            return render(analysis), analysis



# ---------------------------------------------------------------------------
# where the pictures go
# ---------------------------------------------------------------------------

class _Folder:
    """``--out DIR``: frame k's picture as ``DIR/preview_kkkk.png``, whole or not at all."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.written: list[Path] = []

    def show(self, k: int, picture: np.ndarray) -> bool:
        path = self.folder / OUT_NAME.format(k)

        def write(name: str) -> None:
            try:                                # through memory: OpenCV never sees the path
                io.write_image(name, picture)
            except ValueError:
                raise OSError(f"{path}: OpenCV could not write the PNG") from None
            except OSError as exc:              # the user's name, not the temporary one
                raise OSError(exc.errno, exc.strerror, str(path)) from exc
        io.write_atomically(path, write, suffix=".png")
        self.written.append(path)
        return True

    def remove_stale(self) -> int:
        """Remove the pictures of an earlier, longer run (``preview_kkkk.png`` past the last one this run wrote), so
        the folder holds one run; the number removed. Called when the run ends as it should: a run that fails
        halfway leaves the earlier pictures."""
        stale = [p for p in self.folder.glob("preview_*.png")
                 if (m := _OUT_PATTERN.fullmatch(p.name)) and int(m.group(1)) >= len(self.written)]
        for path in stale:
            path.unlink(missing_ok=True)
        return len(stale)

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------------
# the command
# ---------------------------------------------------------------------------

PREVIEW_EPILOG = (f"Headless (--out DIR): one PNG per frame, DIR/{OUT_NAME.format(0)}, ..., written under a "
                  f"temporary name and renamed; {HEADLESS_FRAMES} frames unless --frames N. Without --out: a "
                  "window with the same pictures, until q or Esc (a replay's last picture stays up), or --frames N; "
                  "its keys: e/E exposure and g/G gain down/up (live cameras), t/T threshold down/up, a the "
                  "adaptive threshold, w writes them into the config file (the one read, else ./headplod.toml). "
                  "Without a display, use --out. "
                  "Exit status: 0 success (a fault in one frame is that frame's picture, saying so); 1 unreadable "
                  "input or an output that cannot be written; 2 bad usage (nothing is written).")


class _Usage(Exception):
    """A command-line mistake (exit status 2); the message says what to do."""


def add_preview_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``headplod preview``'s options; returns the parser."""
    parser.add_argument("--source", metavar="SPEC", default="synthetic",
                        help="what to show: a dataset folder, LEFT.avi,RIGHT.avi, 'synthetic[:PRESET]' (default: "
                             "the built-in synthetic sequence), or live cameras 'v4l2:/dev/video0,/dev/video2' "
                             "(v4l2:0,2) or 'v4l2:auto' (the cameras --calib names)")
    parser.add_argument("--calib", metavar="rig.yaml",
                        help="the cameras' rig: epipolar lines and identification (default: the dataset's own "
                             "rig.yaml, or rig.yaml beside the videos; without one, blobs only)")
    parser.add_argument("--markers", metavar="FILE",
                        help="markers.yaml of the glasses (default: the source's, else the contract's model)")
    parser.add_argument("--out", metavar="DIR",
                        help=f"write the annotated frames as DIR/{OUT_NAME.format(0)}, ... instead of a window "
                             "(DIR is made if missing; its parent must exist; not inside the dataset folder "
                             "being read; an earlier preview's pictures there are replaced, and those past this "
                             "run's last removed)")
    parser.add_argument("--frames", type=frame_count, metavar="N",
                        help=f"stop after N frames (default with --out: {HEADLESS_FRAMES}; in a window: until "
                             "q or Esc, the last picture of a replay staying up)")
    parser.add_argument("--threshold", type=threshold_dn, default=None, metavar="DN|adaptive",
                        help="blob threshold in DN or 'adaptive' (default); the window's t/T keys change it")
    parser.add_argument("--snapshot", metavar="PNG", help=argparse.SUPPRESS)   # the window's framebuffer, for tests
    add_quiet_argument(parser, help="no progress on standard error")
    live = parser.add_argument_group("live cameras (--source v4l2:...)")
    add_camera_settings(live, fps_default=None)
    parser.epilog = PREVIEW_EPILOG
    return parser


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (a source spec's list of forms is left to --help)."""
    text = str(exc).split("Accepted forms:")[0].strip()
    if "Accepted forms:" in str(exc):
        text += " (the forms: headplod preview --help)"
    return " ".join(text.split()) or type(exc).__name__


def _check_usage(args) -> tuple[str, Path | None, int | None]:
    """(source spec, --out folder or None, frames or None); raises _Usage. Reads the file system, writes
    nothing."""
    spec = args.source.strip()
    kind = source_kind(spec)
    live = kind == "v4l2"
    given = [name for name, value in (("--fps", args.fps), ("--fourcc", args.fourcc),
                                      ("--exposure", args.exposure), ("--gain", args.gain)) if value is not None]
    if given and not live and not args.quiet:
        # Not refused: the config file's shared camera settings apply to preview too (headplod.toml).
        print(f"note: {', '.join(given)} set live cameras; ignored for the replay {spec!r}", file=sys.stderr)
    if live and v4l2_devices(spec) == "auto" and not args.calib:
        raise _Usage("--source v4l2:auto finds the cameras --calib rig.yaml names; give --calib "
                     "(or name the devices, v4l2:0,2)")
    out = None
    if args.out:
        out = Path(args.out).expanduser()
        _check_out(args, spec=spec)
        if not out.resolve().parent.is_dir():
            raise _Usage(f"--out {args.out}: the folder {out.parent} does not exist; create it first")
    else:
        problem = window_problem()
        if problem:
            raise _Usage(f"no window can be shown: {problem}; write the pictures with --out DIR "
                         f"(e.g. --out preview, {HEADLESS_FRAMES} frames unless --frames N)")
    frames = args.frames if args.frames is not None else (HEADLESS_FRAMES if out is not None else None)
    return spec, out, frames


def _check_out(args, spec: str | None = None, source=None) -> None:
    """Refuse an ``--out DIR`` that is not a folder (a file, a special file), holds a special file among its
    pictures, or lies inside a folder being read or holds a file read as a picture's name (raises _Usage;
    :mod:`headplod.io.files`): by ``spec`` before the source is opened, by ``source`` after."""
    try:
        check_output(args.out, track_inputs(args, spec, source), option="--out", folder=True,
                     entries=(OUT_GLOB,), fix="write the pictures elsewhere")
    except OutputRefused as exc:
        raise _Usage(str(exc)) from None


def _open(args, spec: str, windowed: bool):
    """(source, rig, requested fps or None); raises ValueError, OSError, LookupError, io.ContractError."""
    rig = io.read_rig(args.calib) if args.calib else None
    if source_kind(spec) == "v4l2":
        options = dict(fps=args.fps or LIVE_FPS, fourcc=args.fourcc, exposure=args.exposure, gain=args.gain)
        if rig is not None:
            options.update(width=rig.image_size[0], height=rig.image_size[1], rig=rig)
        source = open_source(spec, **options)
        if not args.quiet:
            print(source.settings_report(text=True), file=sys.stderr)
        return source, rig, args.fps or LIVE_FPS
    preset = synthetic_preset(spec)
    if preset is not None:
        spec = str(ensure_dataset(preset, quiet=args.quiet))
    source = open_source(spec, realtime=windowed)        # a window plays a recording at its own pace
    return source, rig or source.rig, None


def run_preview(args) -> int:
    """Run ``headplod preview`` from parsed arguments; the exit status (module docstring)."""
    try:
        spec, out, frames = _check_usage(args)
    except _Usage as exc:
        print(f"headplod: preview: {exc}", file=sys.stderr)
        return 2
    try:
        markers = io.read_markers(args.markers) if args.markers else None
        source, rig, requested = _open(args, spec, windowed=out is None)
    except (ValueError, OSError, LookupError) as exc:       # io.ContractError is a ValueError
        print(f"headplod: preview: {_one_line(exc)}", file=sys.stderr)
        return 1
    try:
        return _run(args, source, rig, markers, requested, out, frames)
    finally:
        source.close()


def _run(args, source, rig, markers, requested, out: Path | None, frames: int | None) -> int:
    """The frames of an open source to the folder or the window; the exit status."""
    if out is not None:
        try:
            _check_out(args, source=source)
        except _Usage as exc:
            print(f"headplod: preview: {exc}", file=sys.stderr)
            return 2
    for warning in source.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    try:
        previewer = Previewer(rig, markers or source.markers, DetectionParams(threshold_dn=args.threshold),
                              requested_fps=requested)
    except ValueError as exc:                                 # a marker model the rule cannot use
        print(f"headplod: preview: {_one_line(exc)}", file=sys.stderr)
        return 1
    try:
        if out is not None:
            out.mkdir(exist_ok=True)
            output = _Folder(out)
        else:
            output = _window(args, source, previewer)
    except (OSError, WindowUnavailable) as exc:
        where = f"--out {args.out}" if out is not None else "the window"
        hint = "; write the pictures with --out DIR instead" if isinstance(exc, WindowUnavailable) else ""
        print(f"headplod: preview: {where}: {_one_line(exc)}{hint}", file=sys.stderr)
        return 1
    if rig is None and not args.quiet:
        print(f"note: {NO_RIG_NOTE}", file=sys.stderr)
    count, failed, first_failure, advice = 0, 0, None, {}
    progress = Progress(frames, "preview", unit="frame", disable=args.quiet)
    try:
        while frames is None or count < frames:
            frame = source.read()
            if frame is None:
                break
            picture, analysis = previewer.picture(frame)
            frame_shown = frame
            if analysis.error is not None:
                failed += 1
                first_failure = first_failure or f"frame {analysis.index}: {analysis.error}"
            for a in analysis.advice:
                advice.setdefault((a.kind, a.side), [0, a.text])[0] += 1
            try:
                going = output.show(count, picture)
            except OSError as exc:
                print(f"headplod: preview: --out {args.out}: {exc.strerror or _one_line(exc)} "
                      f"({exc.filename or out}); {count} pictures were written before it", file=sys.stderr)
                return 1
            count += 1
            progress.step(f"frame {analysis.index}" + (": failed" if analysis.error else ""))
            _key_messages(output)
            if not going:
                break
        if isinstance(output, PreviewWindow) and frames is None and count:
            def repaint():                  # after a key: say what it did, draw the frame at the new threshold
                _key_messages(output)
                return previewer.picture(frame_shown, again=True)[0]
            output.hold(repaint)            # the replay ended: its last picture stays up until q
            _key_messages(output)
    finally:
        progress.close()
        closing = _close(output)
    if closing is not None:                 # the snapshot (a test's option) could not be written
        print(f"headplod: preview: --snapshot {args.snapshot}: {closing.strerror or _one_line(closing)}",
              file=sys.stderr)
        return 1
    if count == 0:
        print(f"headplod: preview: the source gave no frame ({source.name})", file=sys.stderr)
        return 1
    if isinstance(output, _Folder):
        removed = output.remove_stale()
        if removed and not args.quiet:
            print(f"note: removed {removed} pictures of an earlier, longer preview from {out}", file=sys.stderr)
    _summary(count, failed, first_failure, advice, out, previewer, analysis.index)
    if isinstance(output, PreviewWindow) and output.closed_by:
        print(f"closed with {output.closed_by}")
    return 0


def _window(args, source, previewer: Previewer) -> PreviewWindow:
    """The window, its keys wired to the cameras (live ones only), the previewer's threshold and the config
    file (the one read, else ./headplod.toml)."""
    camera = source if hasattr(source, "set_controls") else None
    config = getattr(args, "config_file", None)

    def config_path() -> Path:              # on w only: a deleted current folder is w's one line then
        return Path(config) if config else Path.cwd() / "headplod.toml"
    controls = Controls(camera, exposure=args.exposure if camera else None, gain=args.gain if camera else None,
                        threshold_dn=args.threshold, set_threshold=previewer.set_threshold,
                        measured_threshold=lambda: previewer.last_threshold_dn, config_path=config_path)
    size = composite_size(*(previewer.size or (640, 480)))
    return PreviewWindow(size, controls, snapshot=args.snapshot)


def _close(output) -> OSError | None:
    """Close the folder or the window; the error writing the window's snapshot, or None."""
    try:
        output.close()
    except OSError as exc:
        return exc
    return None


def _key_messages(output) -> None:
    """What the window's keys did, one line each on standard error."""
    for message in getattr(output, "messages", ()):
        print(f"preview: {message}", file=sys.stderr)
    if hasattr(output, "messages"):
        output.messages.clear()


def _summary(count, failed, first_failure, advice, out, previewer, last_index=None) -> None:
    """The run's lines on standard output: what was written, the frames that failed, the advice by kind."""
    if out is not None:
        w, h = composite_size(*previewer.size) if previewer.size else (0, 0)
        names = OUT_NAME.format(0) + ("" if count == 1 else f" .. {OUT_NAME.format(count - 1)}")
        print(f"wrote {count} annotated frames to {out}: {names} ({w}x{h} px)")
    else:
        print(f"showed {count} frames (the last: frame {last_index})")
    if failed:
        print(f"{failed} of {count} frames failed (first: {first_failure}); each picture says why")
    for times, text in advice.values():
        print(f"advice ({times} of {count} frames): {text}")
