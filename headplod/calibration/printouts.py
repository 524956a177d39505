"""Printouts at true scale: the calibration board (``headplod board``) and the glasses' marker template
(``headplod glasses``).

Both are laid out once, in page millimetres (origin at the sheet's top-left
corner, x right, y down), and drawn by one of two pages: :class:`RasterPage`
(OpenCV, a PNG at ``dpi`` with the dpi in its metadata) or :class:`VectorPage`
(matplotlib, a PDF or SVG whose figure is the paper size in inches). At ``dpi``
one millimetre is ``dpi / 25.4`` px, so a square of S mm is ``S / 25.4 * dpi`` px.

The board is :class:`~headplod.calibration.board.BoardSpec`'s: ``cols`` x ``rows``
inner corners, so ``(cols + 1) x (rows + 1)`` squares, the same numbers that go
to ``headplod calibrate``; a ChArUco board is drawn by
``cv2.aruco.CharucoBoard.generateImage``. The template shows the marker model's
P0..P4 (``markers.yaml``, glasses frame G, mm) seen from the front, the side
that faces the cameras: G's x to the right, y up, z out of the sheet.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Optional

import cv2
import numpy as np

from .. import io
from ..argtypes import add_quiet_argument
from ..io.files import Inputs, OutputRefused, check_files, file_id, output_kind
from .board import BoardSpec, _charuco
from .command import add_board_spec_arguments
from ..tol import tol

#: Paper sizes, (width, height) in mm, portrait.
PAPERS_MM = {"a4": (210.0, 297.0), "letter": (215.9, 279.4)}
#: Endings ``--out`` takes: PNG by OpenCV, PDF and SVG by matplotlib.
OUT_SUFFIXES = (".pdf", ".png", ".svg")
#: Resolutions ``--dpi`` takes (px per inch).
DPI_RANGE = (72, 2400)
#: Edge of the sheet left blank (most printers cannot print it), mm.
PRINT_MARGIN_MM = 5.0
#: White around the board, between it and any text, mm.
QUIET_MM = 4.0
#: Height of a capital letter in the sheet's small text, mm (about 8 pt).
TEXT_MM = 2.0
#: Length of the scale bar, mm.
SCALE_BAR_MM = 100.0
#: Room above and below the board (margin, white, two lines of text or the scale bar), mm.
STRIP_MM = PRINT_MARGIN_MM + QUIET_MM + 2 * TEXT_MM + 2.5
#: Room left and right of the board, mm.
SIDE_MM = PRINT_MARGIN_MM + QUIET_MM


class PrintoutError(ValueError):
    """A printout that cannot be made as asked (the message is one actionable line)."""


# ---------------------------------------------------------------------------
# pages: the same drawing calls, in page mm, for a raster and a vector file
# ---------------------------------------------------------------------------

class RasterPage:
    """A white gray-level sheet of ``size_mm`` at ``dpi``, drawn with OpenCV.

    Coordinates are page mm (origin top-left, y down); pixel (u, v) covers
    [u, u + 1) x [v, v + 1) px of the sheet, so a point at (x, y) mm is drawn
    at (x k - 0.5, y k - 0.5) in OpenCV's pixel-centre convention, k = dpi / 25.4.
    """

    _SHIFT = 8                                  # fixed-point bits of OpenCV's sub-pixel drawing

    def __init__(self, size_mm: tuple[float, float], dpi: float):
        self.size_mm, self.dpi = size_mm, float(dpi)
        self.k = self.dpi / 25.4
        self.image = np.full((round(size_mm[1] * self.k), round(size_mm[0] * self.k)), 255, np.uint8)

    def _fixed(self, x: float, y: float) -> tuple[int, int]:
        s = 1 << self._SHIFT
        return round((x * self.k - 0.5) * s), round((y * self.k - 0.5) * s)

    def rect(self, x: float, y: float, w: float, h: float) -> None:
        """A black rectangle, top-left (x, y), w x h mm."""
        pts = np.array([self._fixed(x, y), self._fixed(x + w, y), self._fixed(x + w, y + h), self._fixed(x, y + h)],
                       np.int32)
        cv2.fillPoly(self.image, [pts], 0, cv2.LINE_8, self._SHIFT)

    def circle(self, x: float, y: float, diameter: float) -> None:
        """A black disc centred at (x, y), ``diameter`` mm."""
        cv2.circle(self.image, self._fixed(x, y), round(diameter / 2 * self.k * (1 << self._SHIFT)), 0, -1,
                   cv2.LINE_AA, self._SHIFT)

    def arrow(self, x0: float, y0: float, x1: float, y1: float, width: float = 0.3) -> None:
        """A black arrow from (x0, y0) to (x1, y1) mm, ``width`` mm thick."""
        length = math.hypot(x1 - x0, y1 - y0)
        cv2.arrowedLine(self.image, self._fixed(x0, y0), self._fixed(x1, y1), 0, max(1, round(width * self.k)),
                        cv2.LINE_AA, self._SHIFT, tipLength=min(0.3, 2.5 / max(length, tol.small)))

    def text(self, x: float, y: float, s: str, height: float = TEXT_MM, align: str = "left",
             max_width: Optional[float] = None) -> None:
        """``s`` with its baseline at y mm, capitals ``height`` mm tall, starting (``align`` 'left') or
        centred ('center') at x; shrunk to ``max_width`` mm if longer."""
        font = cv2.FONT_HERSHEY_SIMPLEX
        (w1, h1), _ = cv2.getTextSize(s, font, 1.0, 1)
        scale = height * self.k / h1
        if max_width is not None and w1 * scale > max_width * self.k:
            scale = max_width * self.k / w1
        thick = max(1, round(scale * h1 / 14))
        (w, _), _ = cv2.getTextSize(s, font, scale, thick)
        u = x * self.k - (w / 2 if align == "center" else 0)
        cv2.putText(self.image, s, (round(u), round(y * self.k)), font, scale, 0, thick, cv2.LINE_AA)

    def image_mm(self, gray: np.ndarray, x: float, y: float, w: float, h: float) -> None:
        """A gray uint8 image filling the box (x, y, w, h) mm (resized, nearest, if its px size differs)."""
        u0, v0 = round(x * self.k), round(y * self.k)
        u1, v1 = round((x + w) * self.k), round((y + h) * self.k)
        if gray.shape != (v1 - v0, u1 - u0):
            gray = cv2.resize(gray, (u1 - u0, v1 - v0), interpolation=cv2.INTER_NEAREST)
        self.image[v0:v1, u0:u1] = gray

    def save(self, path: str) -> None:
        """Write the PNG, with ``dpi`` in its pHYs chunk (through PIL, which matplotlib brings)."""
        from PIL import Image                   # matplotlib's dependency; only needed here
        Image.fromarray(self.image).save(path, format="PNG", dpi=(self.dpi, self.dpi))


class VectorPage:
    """A sheet of ``size_mm`` drawn with matplotlib: a figure of the paper's size in inches whose one axes
    spans it in page mm (origin top-left, y down), saved as PDF or SVG at true size."""

    def __init__(self, size_mm: tuple[float, float], dpi: float):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        self.size_mm, self.dpi = size_mm, float(dpi)
        self.fig = Figure(figsize=(size_mm[0] / 25.4, size_mm[1] / 25.4))
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0, 0, 1, 1))
        self.ax.set_xlim(0, size_mm[0])
        self.ax.set_ylim(size_mm[1], 0)
        self.ax.set_axis_off()

    def rect(self, x, y, w, h):
        from matplotlib.patches import Rectangle
        self.ax.add_patch(Rectangle((x, y), w, h, facecolor="black", edgecolor="none", linewidth=0))

    def circle(self, x, y, diameter):
        from matplotlib.patches import Circle
        self.ax.add_patch(Circle((x, y), diameter / 2, facecolor="black", edgecolor="none", linewidth=0))

    def arrow(self, x0, y0, x1, y1, width=0.3):
        self.ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                         arrowprops=dict(arrowstyle="-|>", color="black", lw=width / 25.4 * 72,
                                         shrinkA=0, shrinkB=0, mutation_scale=8))

    def text(self, x, y, s, height=TEXT_MM, align="left", max_width=None):
        points = height / 0.73 / 25.4 * 72      # DejaVu Sans: capitals are 0.73 of the font size
        t = self.ax.text(x, y, s, fontsize=points, ha=align, va="baseline", color="black")
        if max_width is not None:
            width_mm = t.get_window_extent(self.canvas.get_renderer()).width / self.fig.dpi * 25.4
            if width_mm > max_width:
                t.set_fontsize(points * max_width / width_mm)

    def image_mm(self, gray, x, y, w, h):
        self.ax.imshow(gray, cmap="gray", vmin=0, vmax=255, extent=(x, x + w, y + h, y), interpolation="none")
        self.ax.set_xlim(0, self.size_mm[0])
        self.ax.set_ylim(self.size_mm[1], 0)

    def save(self, path: str) -> None:
        try:
            self.fig.savefig(path, format=Path(path).suffix[1:], dpi=self.dpi)
        except Exception as exc:
            # matplotlib's PDF writer, cleaning up after a write that failed (a full disk), raises an
            # AttributeError of its own: the OSError underneath is what happened.
            if not isinstance(exc, OSError) and isinstance(exc.__context__, OSError):
                raise exc.__context__ from None
            raise


def new_page(out: str, size_mm: tuple[float, float], dpi: float):
    """The page that writes ``out``'s ending: :class:`RasterPage` for .png, :class:`VectorPage` otherwise."""
    return (RasterPage if Path(out).suffix.lower() == ".png" else VectorPage)(size_mm, dpi)


def scale_bar(page, x: float, y: float) -> None:
    """A :data:`SCALE_BAR_MM` bar from (x, y) mm (its top-left): ticks every 10 mm, labelled."""
    page.rect(x, y, SCALE_BAR_MM, 0.6)
    for t in range(0, int(SCALE_BAR_MM) + 1, 10):
        tall = 2.5 if t % 50 == 0 else 1.4
        page.rect(x + t - 0.15 if t else x, y, 0.3, tall)
    page.rect(x + SCALE_BAR_MM - 0.3, y, 0.3, 2.5)
    page.text(x + SCALE_BAR_MM + 2.0, y + 2.5, f"{SCALE_BAR_MM:g} mm: measure it too")


# ---------------------------------------------------------------------------
# checks shared by the two commands (everything is checked before anything is written)
# ---------------------------------------------------------------------------

def check_out(out: str, option: str = "--out", suffixes=OUT_SUFFIXES) -> Path:
    """``out`` as a Path, or :class:`PrintoutError`: an unknown ending, a folder, a missing folder."""
    path = Path(out).expanduser()
    if path.suffix.lower() not in suffixes:
        raise PrintoutError(f"{option} {out}: unknown ending {path.suffix or '(none)'!r}, expected "
                            f"{', '.join(suffixes)}")
    if path.is_dir():
        raise PrintoutError(f"{option} {out}: is a folder; give the file to write, e.g. {path / ('x' + suffixes[0])}")
    try:
        output_kind(out, option=option, stream=True)            # a device node, a FIFO: refused
    except OutputRefused as exc:
        raise PrintoutError(str(exc)) from None
    if not path.resolve().parent.is_dir():
        raise PrintoutError(f"{option} {out}: the folder {path.resolve().parent} does not exist; create it first")
    return path


def check_dpi(dpi: float) -> float:
    if not (math.isfinite(dpi) and DPI_RANGE[0] <= dpi <= DPI_RANGE[1]):
        raise PrintoutError(f"--dpi {dpi:g}: expected {DPI_RANGE[0]} to {DPI_RANGE[1]} px per inch (300 is usual)")
    return float(dpi)


# ---------------------------------------------------------------------------
# the board
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class BoardLayout:
    """Where a board goes on a sheet: ``paper`` (mm, as oriented), ``box`` (x, y, w, h) of the squares, mm."""

    paper_mm: tuple[float, float]
    box: tuple[float, float, float, float]
    landscape: bool


def board_layout(spec: BoardSpec, paper: str) -> BoardLayout:
    """Centre the board's ``(cols + 1) x (rows + 1)`` squares on ``paper`` (portrait or landscape, whichever
    fits, the board's own orientation first), leaving :data:`STRIP_MM` above and below for the note and the
    scale bar and :data:`SIDE_MM` beside it; :class:`PrintoutError` when it fits neither way."""
    pw, ph = PAPERS_MM[paper]
    w, h = (spec.cols + 1) * spec.square_mm, (spec.rows + 1) * spec.square_mm
    orientations = [(ph, pw, True), (pw, ph, False)] if w > h else [(pw, ph, False), (ph, pw, True)]
    for sw, sh, landscape in orientations:
        if w + 2 * SIDE_MM <= sw and h + 2 * STRIP_MM <= sh and SCALE_BAR_MM + 2 * SIDE_MM <= sw:
            return BoardLayout((sw, sh), ((sw - w) / 2, (sh - h) / 2, w, h), landscape)
    largest = max(min((sw - 2 * SIDE_MM) / (spec.cols + 1), (sh - 2 * STRIP_MM) / (spec.rows + 1))
                  for sw, sh, _ in orientations)
    raise PrintoutError(
        f"a {spec.cols}x{spec.rows} board of {spec.square_mm:g} mm squares is {w:g} x {h:g} mm and does not fit "
        f"on {paper} ({pw:g} x {ph:g} mm, less {SIDE_MM:g} mm beside and {STRIP_MM:g} mm above and below it): "
        f"use --square-mm {math.floor(largest * 10) / 10:g} or less, fewer --cols/--rows, or a larger --paper")


def check_board(spec: BoardSpec) -> None:
    """A ChArUco board needs a marker per white square from its dictionary: :class:`PrintoutError` if not."""
    if spec.kind != "charuco":
        return
    needed = (spec.cols + 1) * (spec.rows + 1) // 2
    have = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary)).bytesList.shape[0]
    if needed > have:
        raise PrintoutError(f"a {spec.cols}x{spec.rows} ChArUco board needs {needed} markers and {spec.dictionary} "
                            f"has {have}: use fewer --cols/--rows or a larger --dictionary (e.g. DICT_5X5_250)")


def draw_board(page, spec: BoardSpec, layout: BoardLayout) -> None:
    """The board's squares in ``layout.box`` (square (0, 0), top-left, black, as OpenCV's ChArUco boards),
    the note above it and the scale bar below it."""
    x0, y0, w, h = layout.box
    s = spec.square_mm
    if spec.kind == "chessboard":
        for i in range(spec.rows + 1):
            for j in range(spec.cols + 1):
                if (i + j) % 2 == 0:
                    page.rect(x0 + j * s, y0 + i * s, s, s)
    else:
        board, _ = _charuco(spec)
        k = page.dpi / 25.4
        px = (round((x0 + w) * k) - round(x0 * k), round((y0 + h) * k) - round(y0 * k))
        page.image_mm(board.generateImage(px, marginSize=0, borderBits=1), x0, y0, w, h)
    sw = layout.paper_mm[0]
    usable = sw - 2 * PRINT_MARGIN_MM
    command = (f"headplod calibrate --board {spec.kind} --cols {spec.cols} --rows {spec.rows} "
               f"--square-mm {s:g}" + (f" --marker-mm {spec.marker:g} --dictionary {spec.dictionary}"
                                       if spec.kind == "charuco" else ""))
    note = (f"square {s:.1f} mm: measure it; if it differs, pass the measured size to calibrate --square-mm"
            + (" (and scale --marker-mm alike)" if spec.kind == "charuco" else ""))
    top = y0 - QUIET_MM - TEXT_MM - 1.5
    page.text(sw / 2, top - TEXT_MM - 1.5, f"{spec.describe()}; print at 100 % (not 'fit to page')  |  {command}",
              align="center", max_width=usable)
    page.text(sw / 2, top + TEXT_MM, note, align="center", max_width=usable)
    scale_bar(page, sw / 2 - SCALE_BAR_MM / 2 - 15.0, y0 + h + QUIET_MM)


def make_board(spec: BoardSpec, paper: str, dpi: float, out: str) -> BoardLayout:
    """Write the board to ``out`` (.pdf, .png or .svg) at true scale on ``paper``; the layout used.

    Everything is checked first (:class:`PrintoutError`); the file is written under a temporary name and
    renamed, so ``out`` is whole or untouched.
    """
    path = check_out(out)
    dpi = check_dpi(dpi)
    check_board(spec)
    layout = board_layout(spec, paper)
    page = new_page(out, layout.paper_mm, dpi)
    draw_board(page, spec, layout)
    io.write_atomically(path, page.save, suffix=path.suffix.lower())
    return layout


# ---------------------------------------------------------------------------
# the glasses' template
# ---------------------------------------------------------------------------

def glasses_layout(model: io.MarkerModel, marker_mm: float, paper: str):
    """(paper (w, h) mm, origin (x, y) page mm of G's origin P1): the markers' box centred on ``paper``,
    portrait if it fits, else landscape; :class:`PrintoutError` if neither."""
    P = model.points_mm[:, :2]
    lo, hi = P.min(axis=0) - marker_mm / 2, P.max(axis=0) + marker_mm / 2
    w, h = hi - lo
    pw, ph = PAPERS_MM[paper]
    for sw, sh in ((pw, ph), (ph, pw)):
        if w + 2 * SIDE_MM + 12 <= sw and h + 2 * STRIP_MM + 60 <= sh:
            cx, cy = sw / 2, sh / 2
            return (sw, sh), (cx - (lo[0] + hi[0]) / 2, cy + (lo[1] + hi[1]) / 2)
    raise PrintoutError(f"the markers span {w:.0f} x {h:.0f} mm and do not fit on {paper} ({pw:g} x {ph:g} mm) "
                        "with their labels: check markers.yaml is in mm, or use a larger --paper")


def check_marker_mm(model: io.MarkerModel, marker_mm: float) -> float:
    """``marker_mm`` if positive and smaller than the closest two markers' distance (x, y), else
    :class:`PrintoutError`."""
    P = model.points_mm[:, :2]
    closest = min(np.linalg.norm(P[a] - P[b]) for a in range(5) for b in range(a + 1, 5))
    if not (math.isfinite(marker_mm) and 0 < marker_mm < closest):
        raise PrintoutError(f"--marker-mm {marker_mm:g}: expected a diameter > 0 and < {closest:.1f} mm "
                            "(the closest two markers' distance)")
    return float(marker_mm)


def draw_glasses(page, model: io.MarkerModel, marker_mm: float, paper_mm, origin) -> None:
    """Discs of ``marker_mm`` at P0..P4 (page x = origin x + G x, page y = origin y - G y), labelled, with
    G's axes, a list of the coordinates and the scale bar."""
    ox, oy = origin
    sw, sh = paper_mm
    usable = sw - 2 * PRINT_MARGIN_MM
    P = model.points_mm
    for i, (x, y, _) in enumerate(P):
        page.circle(ox + x, oy - y, marker_mm)
        page.text(ox + x, oy - y + marker_mm / 2 + 2.0 + 3.0, f"P{i}", height=3.0, align="center")
    top = oy - P[:, 1].max() - marker_mm / 2 - 25
    page.text(sw / 2, top, f"headplod glasses: 1:1 template of the five markers, {marker_mm:g} mm discs; "
              "print at 100 % (not 'fit to page')", align="center", max_width=usable)
    page.text(sw / 2, top + TEXT_MM + 2.5, "seen from the front (the side facing the cameras): P1 on the bridge, "
              "P0 on the wearer's left", align="center", max_width=usable)
    coords = "  ".join(f"P{i} ({x:g}, {y:g}, {z:g})" for i, (x, y, z) in enumerate(P))
    below = oy - P[:, 1].min() + marker_mm / 2 + 15
    page.text(sw / 2, below, f"glasses frame G, mm: {coords}", align="center", max_width=usable)
    if np.any(P[:, 2] != 0):
        page.text(sw / 2, below + TEXT_MM + 2.5, "P3/P4 lie off the plane z = 0: the sheet shows (x, y) only",
                  align="center", max_width=usable)
    ax, ay = sw / 2 - 60, below + 30                  # G's axes: x right, y up
    page.arrow(ax, ay, ax + 15, ay)
    page.arrow(ax, ay, ax, ay - 15)
    page.text(ax + 17, ay + TEXT_MM / 2, "x (toward P0)")
    page.text(ax - 1.0, ay - 17, "y (up)")
    page.text(ax + 40, ay - 6, "G: origin P1, x toward P0, y up,", max_width=75)
    page.text(ax + 40, ay - 6 + TEXT_MM + 2, "z out of the sheet (toward the cameras)", max_width=75)
    scale_bar(page, sw / 2 - SCALE_BAR_MM / 2 - 15.0, ay + 12)


class GlassesWritten(NamedTuple):
    """What :func:`make_glasses` wrote: the model drawn, and its markers.yaml (None: none asked for) with what
    became of it: ``written`` (new), ``kept`` (it already held this layout), ``replaced`` (it held another)."""

    model: io.MarkerModel
    yaml: Optional[Path]
    yaml_state: str


def yaml_beside(out: str) -> Path:
    """The markers.yaml that goes with a template ``out`` by default: ``markers.yaml`` in its folder."""
    return Path(out).expanduser().parent / "markers.yaml"


def _held_layout(path: Path, model: io.MarkerModel) -> str:
    """``missing``, ``same`` (``path`` reads as ``model``) or ``different`` (another layout, or not one at all)."""
    if not path.exists():
        return "missing"
    try:
        return "same" if io.read_markers(path) == model else "different"
    except io.ContractError:            # not a markers.yaml at all: not this layout either
        return "different"


def make_glasses(model: io.MarkerModel, marker_mm: Optional[float], paper: str, dpi: float, out: str,
                 yaml: Optional[str] = None, *, replace_different: bool = True) -> GlassesWritten:
    """Write the template of ``model`` with discs of ``marker_mm`` (default the model's diameter) to ``out``
    (.pdf, .png or .svg) and, with ``yaml``, the ``markers.yaml`` of that model and diameter.

    A ``yaml`` that already holds this layout is left as it is; one that holds another is replaced, or with
    ``replace_different`` False (the file was not named, :func:`yaml_beside`) refused (:class:`PrintoutError`).
    Everything is checked first (:class:`PrintoutError`); each file is written under a temporary name and
    renamed.
    """
    path = check_out(out)
    ypath = check_out(yaml, "--yaml", (".yaml", ".yml")) if yaml else None
    if ypath is not None and file_id(ypath).same(file_id(path)):
        raise PrintoutError("--yaml and --out name the same file; give two names")
    dpi = check_dpi(dpi)
    marker_mm = check_marker_mm(model, model.diameter_mm if marker_mm is None else marker_mm)
    paper_mm, origin = glasses_layout(model, marker_mm, paper)
    printed = io.MarkerModel(model.points_mm.copy(), marker_mm)
    held = "missing" if ypath is None else _held_layout(ypath, printed)
    if held == "different" and not replace_different:
        raise PrintoutError(f"{ypath} already holds a different marker layout and is not replaced; name the "
                            "sheet's markers.yaml with --yaml FILE (an existing one is then replaced), or --no-yaml")
    page = new_page(out, paper_mm, dpi)
    draw_glasses(page, printed, marker_mm, paper_mm, origin)
    io.write_atomically(path, page.save, suffix=path.suffix.lower())
    if ypath is not None and held != "same":
        io.write_atomically(ypath, lambda name: io.write_markers(name, printed), suffix=ypath.suffix.lower())
    state = {"missing": "written", "same": "kept", "different": "replaced"}[held]
    return GlassesWritten(printed, ypath, state if ypath is not None else "none")


# ---------------------------------------------------------------------------
# the commands
# ---------------------------------------------------------------------------

def _common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--paper", choices=tuple(PAPERS_MM), default="a4",
                        help="paper size: a4 (210 x 297 mm) or letter (215.9 x 279.4 mm) (default a4)")
    parser.add_argument("--dpi", type=float, default=300.0,
                        help="px per inch of a PNG, and of a ChArUco board's image in a PDF/SVG (default 300)")
    parser.add_argument("--out", required=True, help="file to write: .pdf, .png or .svg")
    add_quiet_argument(parser, help="no line saying what was written (errors still appear)")


def add_board_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``headplod board``'s options: the board as ``headplod calibrate`` takes it, the paper, the file."""
    add_board_spec_arguments(parser)                # calibrate's own options: the same numbers go to both
    _common_arguments(parser)
    return parser


def _write_failed(command: str, exc: OSError, out) -> int:
    """One line for an output that could not be written (the files go under temporary names: none is left
    half-written); exit status 1."""
    print(f"headplod {command}: could not write the output: {exc.strerror or exc} ({exc.filename or out}; "
          "is the disk full or the folder read-only?)", file=sys.stderr)
    return 1


def run_board(args) -> int:
    """Run ``headplod board``; the exit status (2 with one line on stderr for anything that cannot be made)."""
    try:
        spec = BoardSpec(kind=args.board, cols=args.cols, rows=args.rows, square_mm=args.square_mm,
                         marker_mm=args.marker_mm, dictionary=args.dictionary)
        layout = make_board(spec, args.paper, args.dpi, args.out)
    except ValueError as exc:                   # BoardSpec's and PrintoutError
        print(f"headplod board: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:                      # a full disk, a read-only folder: nothing is left behind
        return _write_failed("board", exc, args.out)
    w, h = layout.box[2:]
    if not args.quiet:
        print(f"wrote {args.out}: {spec.describe()}, {w:g} x {h:g} mm on {args.paper} "
              f"{'landscape' if layout.landscape else 'portrait'}; print at 100 % and measure a square")
    return 0


def add_glasses_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``headplod glasses``'s options: the marker model, the disc size, the paper, the files."""
    parser.add_argument("--markers", help="markers.yaml to draw (default: the contract's model, "
                        "P0 (65, 0, 0) .. P4 (-40, -30, 0) mm)")
    parser.add_argument("--marker-mm", type=float,
                        help="marker disc diameter, mm (default the model's, 6 mm for the default model)")
    files = parser.add_mutually_exclusive_group()
    files.add_argument("--yaml", help="the markers.yaml that goes with the sheet (.yaml; default: markers.yaml "
                       "beside --out, never replacing one that holds a different layout; a file named here is "
                       "replaced, and the line says so)")
    files.add_argument("--no-yaml", action="store_true", help="write the sheet alone, no markers.yaml")
    _common_arguments(parser)
    return parser


def run_glasses(args) -> int:
    """Run ``headplod glasses``; the exit status (2 with one line on stderr for anything that cannot be made;
    a bad ``--markers`` file raises :class:`~headplod.io.ContractError`, exit 1)."""
    model = io.read_markers(args.markers) if args.markers else io.default_marker_model()
    yaml = None if args.no_yaml else (args.yaml or str(yaml_beside(args.out)))
    try:
        if args.markers:                        # the sheet's files are never the markers.yaml being read
            named = [("--out", args.out)] + ([("--yaml", args.yaml)] if args.yaml else [])
            # (the markers.yaml beside may be the one read: then it holds the layout drawn and is left as it is,
            # or a --marker-mm changes it and it is refused as a different layout)
            check_files(named, Inputs().file("the markers being read (--markers)", args.markers))
        done = make_glasses(model, args.marker_mm, args.paper, args.dpi, args.out, yaml,
                            replace_different=args.yaml is not None)
    except (PrintoutError, OutputRefused) as exc:
        print(f"headplod glasses: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        return _write_failed("glasses", exc, args.out)
    also = {"written": f" and {yaml}", "replaced": f" and {yaml} (replacing the different layout it held)",
            "kept": f" ({yaml} already holds this layout, left as it is)", "none": ""}[done.yaml_state]
    if not args.quiet:
        print(f"wrote {args.out}{also}: five {done.model.diameter_mm:g} mm markers on {args.paper}; "
              "print at 100 % and check the scale bar")
    return 0
