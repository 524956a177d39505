"""The one frame step (headplod.render.frame): the settings mean the same on every back end.

Every back end × uncertainty scenario runs the same fixed pose sequence:

- ``none`` ignores the covariance: the frames are the same whatever covariance the tracker gives;
- ``fixed``, ``adaptive`` and ``smoothed`` move the detail the same way on every back end: a larger
  covariance never draws less, and after the covariance drops, ``fixed`` keeps the most, ``adaptive``
  the least and ``smoothed`` lies between;
- every back end reads the same conditioned view (one conditioning step per frame).
"""
import dataclasses

import numpy as np
import pytest

from headplod.plod.select import SelectorConfig
from headplod.plod.view import UNCERTAINTY_MODES, View
from headplod.render.frame import (BACKENDS, CAPABILITIES, DEMO_BACKENDS, FrameSettings, capability_table,
                                   make_frame_step, options_problem)

SIZE = (320, 180)
RAYMASK_SIZE = (640, 360)     # below about 10 px/deg the ray mask casts a ray through every pixel whatever the view
SMALL = np.diag([0.05 ** 2, 0.05 ** 2])          # a tracker's σ of V at 60 cm, deg²
LARGE = np.diag([1.5 ** 2, 3.0 ** 2])
FRAMES = 6
DROP_AT = 3                                       # the covariance drops from LARGE to SMALL here


def _poses(screen, cov_before, cov_after=None):
    """A head drifting slowly (tracker-like noise, fixed seed) looking near the screen centre."""
    from headplod.render.still import default_head

    rng = np.random.default_rng(7)
    head = default_head(screen)
    centre = np.array(screen.size_px, float) / 2 + [120.0, -60.0]
    cov_after = cov_before if cov_after is None else cov_after
    return [View(head + rng.normal(0, 0.3, 3), centre + rng.normal(0, 2.0, 2),
                 cov_before if k < DROP_AT else cov_after, k / 30) for k in range(FRAMES)]


@pytest.fixture(scope="module")
def backends(gl_context, ctx430, terrain_scene):
    """Frame steps: name -> callable(config) -> FrameStep of that back end, all on the same terrain, placed alike."""
    from headplod.plod.patches import PatchGrid, height_grid
    from headplod.render.gl import TerrainRenderer
    from headplod.render.raymask import RayMaskRenderer
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    renderer = TerrainRenderer(gl_context, size=SIZE)
    rays = RayMaskRenderer(gl_context, terrain_scene.mesh, size=RAYMASK_SIZE)
    scene = terrain_scene
    z, dx, dy = height_grid(scene.terrain, 257)
    grid = PatchGrid.build(z, dx, dy, 16, origin_m=(scene.terrain.extent[0], scene.terrain.extent[2]))
    tess = TessellationRenderer(ctx430, grid, size=SIZE, config=TessellationConfig(patch_samples=16))

    def mesh(config):
        return make_frame_step(FrameSettings("mesh", config), scene.screen, renderer=renderer, scene=scene,
                               mesh=scene.mesh.share())

    def raymask(config):
        return make_frame_step(FrameSettings("raymask", config), scene.screen, renderer=rays)

    def tessellation(config):
        return make_frame_step(FrameSettings("tessellation", config), scene.screen, renderer=tess)

    yield {"mesh": mesh, "raymask": raymask, "tessellation": tessellation}
    tess.release()
    rays.release()
    renderer.release()


def _run(factory, screen, model, scenario, poses):
    # Every back end draws csf, the paper's rule, which every one of them takes: the scenarios' shift of the
    # eccentricity by the covariance is its rule. (The default mode, hybrid, weighs the whole gaze distribution
    # instead, the eye-in-head prior included, against which a tracker's covariance changes little:
    # tests/test_gaze_prior.py.)
    step = factory(SelectorConfig(mode="csf", uncertainty=scenario))
    return [step(v, model) for v in poses]


def _detail(out) -> float:
    """How much detail a frame asks for: the mesh's mean level, the patches' triangles, or the ray mask's
    rays (the inset's and the rings'; the silhouettes' depend on the terrain under the rays, not on the mask)."""
    if out.levels is not None:
        return float(out.levels.mean())
    if "raymask" not in out.details:
        return float(out.triangles)
    return float(out.details["raymask"]["fill_rays"] + out.details["raymask"]["ring_rays"])


@pytest.mark.slow
@pytest.mark.parametrize("name", BACKENDS)
def test_none_ignores_the_covariance(backends, terrain_scene, name):
    screen, model = terrain_scene.screen, terrain_scene.model
    runs = [_run(backends[name], screen, model, "none", _poses(screen, cov)) for cov in (None, SMALL, LARGE)]
    for a, b in zip(runs[0], runs[2]):
        assert a.view.cov_deg2 is None and b.view.cov_deg2 is None
        np.testing.assert_array_equal(a.image, b.image)
        if a.levels is not None:
            np.testing.assert_array_equal(a.levels, b.levels)
    assert all(np.array_equal(a.image, b.image) for a, b in zip(runs[0], runs[1]))


@pytest.mark.slow
@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("scenario", ["fixed", "adaptive", "smoothed"])
def test_a_larger_covariance_never_draws_less(backends, terrain_scene, name, scenario):
    screen, model = terrain_scene.screen, terrain_scene.model
    small = _run(backends[name], screen, model, scenario, _poses(screen, SMALL))
    large = _run(backends[name], screen, model, scenario, _poses(screen, LARGE))
    for s, l in zip(small, large):
        assert _detail(l) >= _detail(s)
    assert sum(map(_detail, large)) > sum(map(_detail, small))


@pytest.mark.slow
@pytest.mark.parametrize("name", BACKENDS)
def test_after_the_covariance_drops_fixed_keeps_most_and_adaptive_least(backends, terrain_scene, name):
    screen, model = terrain_scene.screen, terrain_scene.model
    poses = _poses(screen, LARGE, SMALL)
    detail = {sc: [_detail(o) for o in _run(backends[name], screen, model, sc, poses)[DROP_AT + 1:]]
              for sc in ("fixed", "adaptive", "smoothed")}
    # The ray mask's count moves in steps of its rings and angles: a ray or ten either way of 230k.
    slack = 1 - 1e-4 if name == "raymask" else 1.0
    for f, a, s in zip(detail["fixed"], detail["adaptive"], detail["smoothed"]):
        assert f >= s * slack and s >= a * slack
    assert sum(detail["fixed"]) > sum(detail["adaptive"])


@pytest.mark.slow
def test_every_back_end_reads_the_same_conditioned_view(backends, terrain_scene):
    screen, model = terrain_scene.screen, terrain_scene.model
    poses = _poses(screen, LARGE, SMALL)
    views = {name: [o.view for o in _run(backends[name], screen, model, "smoothed", poses)] for name in backends}
    for a, b in [*zip(views["mesh"], views["raymask"]), *zip(views["mesh"], views["tessellation"])]:
        for f in dataclasses.fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if isinstance(x, np.ndarray):
                np.testing.assert_array_equal(x, y)
            else:
                assert x == y, f.name
    # The conditioning did something: the filtered eye is not the raw one after the first frame.
    assert not np.array_equal(views["mesh"][-1].eye_mm, views["mesh"][-1].raw_eye_mm)


@pytest.mark.slow
def test_a_saccade_keeps_the_last_levels(backends, terrain_scene):
    screen, model = terrain_scene.screen, terrain_scene.model
    config = SelectorConfig(uncertainty="none")
    step = backends["mesh"](config)
    poses = _poses(screen, None)
    first = step(poses[0], model)
    jump = dataclasses.replace(poses[1], poi_px=poses[0].poi_px + [900.0, 0.0])   # ~30° in 1/30 s
    held = step(jump, model)
    assert held.held and held.view.saccade and held.view.poi_speed_deg_s > config.saccade_hold_deg_s
    np.testing.assert_array_equal(held.levels, first.levels)
    after = step(dataclasses.replace(poses[2], poi_px=jump.poi_px), model)        # the eye has landed
    assert not after.held and not np.array_equal(after.levels, first.levels)


def test_the_capability_table_is_what_the_commands_check():
    for name in BACKENDS:
        cap = CAPABILITIES[name]
        assert options_problem(name, mode=cap.modes[0]) is None
        for scenario in UNCERTAINTY_MODES:
            assert (options_problem(name, mode=cap.modes[0], uncertainty=scenario) is None) == \
                (scenario in cap.scenarios)
        assert (options_problem(name, mode=cap.modes[0], foveate=True) is None) == cap.foveate
        assert (options_problem(name, mode=cap.modes[0], export=True) is None) == cap.export
        for view in ("shaded", "wire", "levels"):
            assert (options_problem(name, mode=cap.modes[0], view_mode=view) is None) == (view in cap.view_modes)
    assert "does not take --mode sse" in options_problem("tessellation", mode="sse")
    for name in BACKENDS:            # the rules that once sat in the commands, from the table now
        cap = CAPABILITIES[name]
        assert (options_problem(name, mode=cap.modes[0], compare=True) is None) == cap.compare
        assert (options_problem(name, mode=cap.modes[0], mesh_options=("--lazy",)) is None) == cap.mesh_options
        for mode in cap.modes:
            takes_csf = cap.csf_modes is None or mode in cap.csf_modes
            assert (options_problem(name, mode=mode, csf=cap.csf_forms[-1]) is None) == takes_csf, (name, mode)
    assert DEMO_BACKENDS == tuple(n for n in BACKENDS if CAPABILITIES[n].demo) and "tessellation" not in DEMO_BACKENDS
    assert not CAPABILITIES["raymask"].lazy_mesh and CAPABILITIES["mesh"].lazy_mesh
    table = capability_table()
    assert all(name in table for name in BACKENDS) and len(table.splitlines()) == len(BACKENDS) + 1


def test_the_docs_show_the_capability_table_of_the_code():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "plod-backends.md").read_text()
    start = text.index("<!-- capability table")
    body = text[text.index("\n", start) + 1:text.index("<!-- end of capability table -->")].strip()
    assert body == capability_table(markdown=True)


def test_frame_settings_default_to_the_back_ends_mode_and_refuse_what_it_cannot_draw():
    for name in BACKENDS:
        assert FrameSettings(name).selection == SelectorConfig(mode=CAPABILITIES[name].default_mode)
    with pytest.raises(ValueError, match="does not take --mode sse"):
        FrameSettings("tessellation", SelectorConfig(mode="sse"))
    with pytest.raises(ValueError, match="--foveate"):
        FrameSettings("raymask", foveate=True)
    with pytest.raises(ValueError, match="unknown back end"):
        FrameSettings("vulkan")
    with pytest.raises(ValueError, match="draw=False"):
        FrameSettings("raymask", draw=False)


def test_frame_step_is_assembled_in_one_function():
    """``FrameStep(...)`` is called in exactly one function of headplod/ (make_frame_step); every command,
    the demo and every bench go through it."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "headplod"
    callers = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        stack = [(tree, None)]
        while stack:
            node, function = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                function = node.name
            if (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None))
                    == "FrameStep"):
                callers.append((str(path.relative_to(root)), function))
            stack.extend((child, function) for child in ast.iter_child_nodes(node))
    assert callers == [("render/frame.py", "make_frame_step")], callers
