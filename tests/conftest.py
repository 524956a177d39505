"""Fixtures shared by the test modules.

Each fixture is defined here once; a test module that needs a variant builds
it from these (e.g. ``small_rig(rms_px=0.3)``) rather than copying them.

- ``sweep12_dir``: the shared sample dataset (tests/data/sweep12, rendered by
  independent code), read only; ``sample``: a writable copy of it;
  ``long_dataset``: its frames six times over (72), to interrupt a run.
- ``small_rig``, ``make_dataset``: a tiny 64x48 rig and contract dataset
  folders built on it, for tests of files and sources that need no markers.
- ``synth``: synthetic presets rendered once per session.
- ``default_screen``, ``terrain_scene``: the embedded screen and the PLOD terrain behind it.
- ``gl_context``: a headless OpenGL context per module, or a skip that says why.
- (autouse) no test reads the user's own config file (``$XDG_CONFIG_HOME`` points at an empty folder).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture.synthetic import ensure_dataset

DATA = Path(__file__).parent / "data"


@pytest.fixture(autouse=True)
def _no_user_config(tmp_path_factory, monkeypatch):
    """No test reads the config file of the person running the tests (~/.config/headplod/config.toml): the
    command line's lookup finds an empty folder instead (tests/test_config.py sets its own)."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path_factory.getbasetemp() / "no-user-config"))


# ---------------------------------------------------------------------------
# the shared sample dataset
# ---------------------------------------------------------------------------


@pytest.fixture(scope="session")
def sweep12_dir() -> Path:
    """tests/data/sweep12: 12 frames, 640x480, with times.csv and truth.csv. Read only: copy it (``sample``)
    before changing anything."""
    return DATA / "sweep12"


@pytest.fixture(scope="session")
def sweep12_rig(sweep12_dir) -> io.Rig:
    """The sample dataset's rig.yaml."""
    return io.read_rig(sweep12_dir / "rig.yaml")


@pytest.fixture(scope="session")
def long_dataset(tmp_path_factory) -> Path:
    """72 frames: the sample's 12, hard-linked six times over, at 30 Hz (about a second of tracking and
    recording: long enough to interrupt). Read only."""
    src = DATA / "sweep12"
    dst = tmp_path_factory.mktemp("long") / "long"
    for side in ("left", "right"):
        (dst / side).mkdir(parents=True)
    shutil.copy(src / "rig.yaml", dst / "rig.yaml")
    for i in range(72):
        for side in ("left", "right"):
            os.link(src / side / f"{i % 12:06d}.png", dst / side / f"{i:06d}.png")
    io.write_times(dst / "times.csv", {i: i / 30 for i in range(72)})
    return dst


@pytest.fixture
def sample(tmp_path, sweep12_dir) -> Path:
    """A writable copy of the sample dataset at ``tmp_path / "ds"``."""
    dst = tmp_path / "ds"
    shutil.copytree(sweep12_dir, dst)
    return dst


# ---------------------------------------------------------------------------
# a tiny rig and datasets on it
# ---------------------------------------------------------------------------

SMALL_SIZE = (64, 48)        # px, width x height


def _small_rig(**extra) -> io.Rig:
    K1 = np.array([[60.0, 0, 32], [0, 61, 24], [0, 0, 1]])
    K2 = np.array([[62.0, 0, 31], [0, 63, 23], [0, 0, 1]])
    D1 = np.array([0.1, -0.05, 0.001, 0.002, 0.01])
    R = cv2.Rodrigues(np.array([0.01, 0.15, -0.02]))[0]
    T = np.array([-350.0, -4.0, 27.0])
    return io.Rig(SMALL_SIZE, K1, D1, K2, np.zeros(5), R, T, extra=extra)


@pytest.fixture
def small_rig():
    """``small_rig(**extra) -> io.Rig``: a valid 64x48 rig (350 mm baseline, some distortion on the
    left camera) with ``extra`` as its extra keys; a new object on every call."""
    return _small_rig


@pytest.fixture
def make_dataset():
    """``make_dataset(folder, n=5, times=None) -> folder``: a valid contract dataset of ``n`` 64x48
    frames on ``small_rig()``, each image different (uniform noise, fixed seed), with ``times.csv``
    written from ``times`` (any form :func:`io.write_times` takes) when given."""

    def make(folder: Path, n: int = 5, times: dict | None = None) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        io.write_rig(folder / "rig.yaml", _small_rig())
        rng = np.random.default_rng(0)
        w, h = SMALL_SIZE
        for side in ("left", "right"):
            (folder / side).mkdir(exist_ok=True)
        for i in range(n):
            for side in ("left", "right"):
                assert cv2.imwrite(str(folder / side / f"{i:06d}.png"), rng.integers(0, 256, (h, w), dtype=np.uint8))
        if times is not None:
            io.write_times(folder / "times.csv", times)
        return folder

    return make


# ---------------------------------------------------------------------------
# synthetic presets
# ---------------------------------------------------------------------------


@pytest.fixture(scope="session")
def synth(tmp_path_factory):
    """Render (once per session) a synthetic preset into a temporary cache; returns an io.Dataset."""
    root = tmp_path_factory.mktemp("synthetic")

    def make(preset, frames, **options):
        return io.Dataset(ensure_dataset(preset, frames=frames, root=root, quiet=True, **options))
    return make


# ---------------------------------------------------------------------------
# the screen and the terrain
# ---------------------------------------------------------------------------


@pytest.fixture(scope="session")
def default_screen() -> io.Screen:
    """The embedded 24-inch screen (calib/screen.yaml), 1920x1080."""
    from calib import DEFAULT_SCREEN

    return io.read_screen(DEFAULT_SCREEN)


@pytest.fixture(scope="module")
def ctx430():
    """A headless OpenGL 4.3 context (tessellation and storage buffers; Mesa llvmpipe has it), or a skip saying why."""
    from headplod.render import create_context

    try:
        ctx = create_context(require=430)
    except RuntimeError as exc:
        pytest.skip(f"no headless OpenGL 4.3: {exc}")
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def terrain_scene(default_screen):
    """The PLOD terrain scene (Jacksboro DEM, 2048 base faces up to level 5) behind the default screen.
    Built once per module (a few seconds): the modules do not share its mesh state."""
    from headplod.render.still import TerrainScene

    return TerrainScene.build(default_screen)


# ---------------------------------------------------------------------------
# OpenGL
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gl_context():
    """A headless (EGL) OpenGL context for one test module, released after it; the module's GL tests
    skip, saying why, on a machine without EGL / Mesa."""
    from headplod.render import create_context

    try:
        ctx = create_context()
    except RuntimeError as exc:
        pytest.skip(f"no headless OpenGL: {exc}")
    yield ctx
    ctx.release()


@pytest.fixture(scope="session")
def screen_plane_field():
    """:func:`_screen_plane_field`, for tests that lay base triangles on the screen's plane."""
    return _screen_plane_field


def _screen_plane_field(u, v, contrast, max_level=5, edge0_mm=14.0):
    """Base triangles on the default screen's plane (scene = world, mm), ``edge0_mm`` wide at level 0.

    ``u``, ``v``: fractions of the screen's width and height of the triangle
    centroids (a grid of them); ``contrast``: a value or one per triangle.
    The eye is 600 mm in front of the screen's centre, on the side the
    cameras see the head from. Returns (screen, centroids (n, 3) mm, edge
    lengths (n, L+1) mm, geometric errors (n, L+1) mm, contrast (n,), eye
    (3,) mm, centroids' screen pixels (n, 2)).
    """
    from calib import DEFAULT_SCREEN
    from headplod.render.still import default_head

    screen = io.read_screen(DEFAULT_SCREEN)
    uu, vv = np.meshgrid(u, v)
    px = np.stack([uu.ravel() * screen.size_px[0], vv.ravel() * screen.size_px[1]], axis=1)
    centroids = screen.pixel_to_world(px)
    edge = edge0_mm / 2.0 ** np.arange(max_level + 1)
    edge_len = np.tile(edge, (len(centroids), 1))
    error = np.tile(0.5 * edge ** 2 / edge0_mm, (len(centroids), 1))
    error[:, -1] = 0.0
    contrast = np.broadcast_to(np.asarray(contrast, np.float64), (len(centroids),)).copy()
    return screen, centroids, edge_len, error, contrast, default_head(screen), px


def field_change_features(field):
    """Mode change's features (headplod.plod.change) for a :func:`_screen_plane_field`: each level removes
    half the contrast the level before did (none at the finest), normals facing the viewer (along the
    screen's normal), a 10° cone. (change_contrast (n, L+1), normal_axis (n, 3), normal_cone_deg (n,))."""
    screen, centroids, edge_len, error, contrast, eye, px = field
    change = np.asarray(contrast)[:, None] * 0.5 ** np.arange(edge_len.shape[1])
    change[:, -1] = 0.0
    axis = np.broadcast_to(-np.asarray(screen.normal), centroids.shape).copy()
    return change, axis, np.full(len(centroids), 10.0)


class FlatTerrain:
    """z = 0 over a rectangle: exact areas are known."""

    extent = (0.0, 3000.0, 0.0, 2000.0)

    def heights(self, x, y):
        return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape)

    def normals(self, x, y):
        n = np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape + (3,))
        n[..., 2] = 1.0
        return n


def load_tool(name: str):
    """The module ``tools/<name>.py`` (the tools are scripts, not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
