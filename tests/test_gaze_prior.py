"""The eye-in-head gaze prior (``--gaze-prior``, :attr:`SelectorConfig.gaze_prior_deg`) and mode ``hybrid``.

Where the viewer looks is the head's direction V plus the eyes' offset in the head, whose σ the prior gives;
the conditioned view's covariance is the tracker's plus that prior (:func:`view.gaze_covariance`), and mode
``hybrid`` weighs what a level removes over Gauss–Hermite nodes of that distribution
(:func:`criteria.gaze_nodes_deg`). Checked here against direct computations: the nodes' moments, the
covariance sum, the angles between 3-D directions; the selector's levels against mode ``sse``'s; the
command line end to end.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from headplod import cli
from headplod.plod import criteria
from headplod.plod import perception as pc
from headplod.plod.select import GAZE_PRIOR_DEG, MAX_GAZE_PRIOR_DEG, SelectorConfig
from headplod.plod.view import ViewConditioner, gaze_covariance, still_view
from raw_views import RawViews

# The nodes' moments are sums of a few dozen products of O(10²) deg² terms: exact but for rounding.
MOMENT_TOL = 1e-9
# Angles through arccos of unit vectors: about 1e-8 rad of rounding near 0°, far below 1e-6 deg elsewhere.
ANGLE_TOL_DEG = 1e-5


def _rotated(sigma_major: float, sigma_minor: float, angle_deg: float) -> np.ndarray:
    """(2, 2) covariance with σ ``sigma_major`` along a direction ``angle_deg`` from the φ axis, ``sigma_minor``
    across it."""
    a = np.radians(angle_deg)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return r @ np.diag([sigma_major ** 2, sigma_minor ** 2]) @ r.T


# ---------------------------------------------------------------------------
# the gaze distribution's nodes
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("cov", [np.diag([36.0, 64.0]), _rotated(9.0, 2.0, 35.0), _rotated(4.0, 0.5, -70.0)],
                         ids=["axis-aligned", "rotated-35", "rotated-minus-70-thin"])
@pytest.mark.parametrize("per_axis", [2, 3, 5])
def test_the_nodes_have_the_distributions_mean_and_covariance(cov, per_axis):
    nodes, weights = criteria.gaze_nodes_deg(cov, per_axis)
    assert nodes.shape == (per_axis ** 2, 2) and weights.shape == (per_axis ** 2,)
    assert np.all(weights > 0)
    assert weights.sum() == pytest.approx(1.0, abs=MOMENT_TOL)
    np.testing.assert_allclose(weights @ nodes, 0.0, atol=MOMENT_TOL)
    np.testing.assert_allclose(np.einsum("k,ki,kj->ij", weights, nodes, nodes), cov, atol=MOMENT_TOL * 100)


@pytest.mark.parametrize("per_axis", [3, 5])
def test_the_nodes_integrate_a_fourth_moment_exactly(per_axis):
    """A normal distribution's E[(u·x)⁴] is 3 (uᵀΣu)² in every direction u; a product rule of n ≥ 3 nodes per
    axis integrates degree-4 polynomials exactly, so the nodes must give it for any u (not only the axes)."""
    cov = _rotated(7.0, 3.0, 20.0)
    nodes, weights = criteria.gaze_nodes_deg(cov, per_axis)
    for angle in np.radians([0.0, 33.0, 90.0, 147.0]):
        u = np.array([np.cos(angle), np.sin(angle)])
        assert weights @ (nodes @ u) ** 4 == pytest.approx(3 * (u @ cov @ u) ** 2, rel=1e-12)


@pytest.mark.parametrize("cov", [None, np.zeros((2, 2))], ids=["None", "zeros"])
def test_no_spread_is_one_node_at_v(cov):
    nodes, weights = criteria.gaze_nodes_deg(cov, 5)
    np.testing.assert_array_equal(nodes, np.zeros((1, 2)))
    np.testing.assert_array_equal(weights, np.ones(1))


# ---------------------------------------------------------------------------
# the covariance the selection uses
# ---------------------------------------------------------------------------

def test_a_zero_prior_leaves_the_trackers_covariance_alone():
    tracker = np.array([[2.0, 0.3], [0.3, 1.5]])
    assert gaze_covariance(tracker, (0.0, 0.0)) is tracker
    assert gaze_covariance(None, (0.0, 0.0)) is None


def test_a_prior_adds_vertical_then_horizontal_variance():
    """(φ, θ) is (vertical, horizontal): a prior (SH, SV) adds diag(SV², SH²)."""
    tracker = np.array([[2.0, 0.3], [0.3, 1.5]])
    np.testing.assert_array_equal(gaze_covariance(tracker, (5.0, 2.0)), tracker + np.diag([4.0, 25.0]))
    np.testing.assert_array_equal(gaze_covariance(None, (5.0, 2.0)), np.diag([4.0, 25.0]))
    np.testing.assert_array_equal(tracker, [[2.0, 0.3], [0.3, 1.5]])        # the tracker's is not changed


@pytest.mark.parametrize("mode, prior, expected", [
    ("sse", None, None),                                                     # a head-only mode: no prior
    ("sse", (5.0, 2.0), np.diag([4.0, 25.0])),                               # given: every mode takes it
    ("hybrid", None, np.diag([GAZE_PRIOR_DEG[1] ** 2, GAZE_PRIOR_DEG[0] ** 2])),   # hybrid's own
    ("hybrid", (0.0, 0.0), None),                                            # 0,0: the paper's head-only view
])
def test_the_conditioned_view_carries_the_prior_in_use(default_screen, mode, prior, expected):
    config = SelectorConfig(mode=mode, uncertainty="none", gaze_prior_deg=prior)
    cv = ViewConditioner(default_screen, config)(still_view(default_screen, cov_deg2=np.eye(2)))
    if expected is None:
        assert cv.cov_deg2 is None
    else:
        np.testing.assert_array_equal(cv.cov_deg2, expected)


def test_the_prior_adds_to_the_scenarios_covariance(default_screen):
    tracker = np.array([[1.0, 0.2], [0.2, 3.0]])
    config = SelectorConfig(mode="csf", uncertainty="adaptive", gaze_prior_deg=(3.0, 1.0))
    cv = ViewConditioner(default_screen, config)(still_view(default_screen, cov_deg2=tracker))
    np.testing.assert_allclose(cv.cov_deg2, tracker + np.diag([1.0, 9.0]))


# ---------------------------------------------------------------------------
# eccentricity from each gaze node
# ---------------------------------------------------------------------------

def test_node_eccentricity_is_the_angle_between_the_directions_less_the_reach():
    """Pieces and gaze nodes as points in front of an eye in a tilted head frame; the expected eccentricity is
    the 3-D angle between eye→piece and eye→node (atan2 of |a×b| and a·b), less the piece's reach, floored."""
    rng = np.random.default_rng(7)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    axes = q.T * np.sign(np.linalg.det(q))                    # rows Ξ, Ψ, V, right-handed
    eye = np.array([30.0, -40.0, 600.0])
    local = lambda x, y, z: np.stack([x, y, z], -1) @ axes   # head-frame (Ξ, Ψ, V) mm → world offset
    pieces = eye + local(rng.uniform(-300, 300, 6), rng.uniform(-200, 200, 6), rng.uniform(300, 900, 6))
    looks = eye + local(np.array([0.0, 80.0, -150.0, 10.0]), np.array([0.0, -60.0, 40.0, 120.0]),
                        np.full(4, 500.0))
    reach = np.array([0.0, 0.5, 2.0, 90.0, 1.0, 0.0])        # one piece reaches every node: eccentricity 0
    got = criteria.node_eccentricity_deg(pc.view_offsets_deg(pieces, eye, axes), reach,
                                         pc.view_offsets_deg(looks, eye, axes))
    a, b = pieces - eye, looks - eye
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(a[:, None], b[None]), axis=-1),
                                  np.einsum("si,ki->sk", a, b)))
    assert got.shape == (6, 4)
    np.testing.assert_allclose(got, np.maximum(angle - reach[:, None], 0.0), atol=ANGLE_TOL_DEG)
    assert np.all(got[3] == 0.0) and np.all(got[[0, 1, 2, 4, 5]] > 0)


def test_from_v_the_node_eccentricity_is_the_pieces_own():
    offsets = np.array([[0.0, 0.0], [3.0, -4.0], [-20.0, 35.0]])
    reach = np.array([0.0, 1.0, 2.5])
    np.testing.assert_allclose(criteria.node_eccentricity_deg(offsets, reach, np.zeros((1, 2)))[:, 0],
                               criteria.piece_eccentricity_deg(offsets, reach), atol=ANGLE_TOL_DEG)


# ---------------------------------------------------------------------------
# hybrid's mix
# ---------------------------------------------------------------------------

def test_hybrid_is_sse_at_share_0_and_change_at_share_1():
    rng = np.random.default_rng(3)
    sse = rng.uniform(0.0, 5.0, 40)
    # log2 visibility per level (S, 6), falling with the level as a finer level removes less
    visibility = rng.uniform(2.0, 6.0, (40, 1)) - np.cumsum(rng.uniform(0.5, 2.0, (40, 6)), axis=1)
    np.testing.assert_array_equal(criteria.hybrid_level(sse, visibility, 0.0), sse)
    np.testing.assert_array_equal(criteria.hybrid_level(sse, None, 0.0), sse)     # no visibility needed then
    np.testing.assert_allclose(criteria.hybrid_level(sse, visibility, 1.0), criteria.change_level(visibility),
                               rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------
# the selector, built as the benches build it
# ---------------------------------------------------------------------------

def _levels(scene, view, mode, **settings):
    """Levels (F,) and features of a hysteresis-free selector over ``scene`` (render.still.TerrainScene.selector,
    as bench.harness.mesh_step makes it), for one still view, with the scenario ``none``: the prior alone."""
    return RawViews(scene.selector(mode, "none", hysteresis=False, **settings)).select(view)


@pytest.mark.slow
def test_hybrid_at_share_0_and_no_prior_chooses_sses_levels(terrain_scene, default_screen):
    view = still_view(default_screen)
    sse, _ = _levels(terrain_scene, view, "sse")
    hybrid, info = _levels(terrain_scene, view, "hybrid", change_share=0.0, gaze_prior_deg=(0.0, 0.0))
    assert len(np.unique(sse)) >= 3                          # a real selection, not one level everywhere
    np.testing.assert_array_equal(hybrid, sse)
    assert info["cov_deg2"] is None
    # sse's level does not depend on where the viewer looks: at share 0 a prior changes nothing either
    wide, _ = _levels(terrain_scene, view, "hybrid", change_share=0.0, gaze_prior_deg=(10.0, 7.0))
    np.testing.assert_array_equal(wide, sse)


@pytest.mark.slow
def test_a_gaze_prior_changes_hybrids_levels(terrain_scene, default_screen):
    view = still_view(default_screen)
    head_only, _ = _levels(terrain_scene, view, "hybrid", gaze_prior_deg=(0.0, 0.0))
    wide, info = _levels(terrain_scene, view, "hybrid", gaze_prior_deg=(10.0, 7.0))
    own, _ = _levels(terrain_scene, view, "hybrid")          # None: hybrid's own, GAZE_PRIOR_DEG
    given, _ = _levels(terrain_scene, view, "hybrid", gaze_prior_deg=GAZE_PRIOR_DEG)
    assert np.count_nonzero(wide != head_only) > 50
    np.testing.assert_array_equal(info["cov_deg2"], np.diag([49.0, 100.0]))
    np.testing.assert_array_equal(own, given)


@pytest.mark.slow
@pytest.mark.parametrize("share", [SelectorConfig().change_share, 1.0])
def test_a_wider_prior_moves_the_detail_away_from_the_poi(terrain_scene, default_screen, share):
    """The wider the distribution of where the viewer looks, the less the POI's neighbourhood stands out:
    the drawn levels within 2° of the POI fall, their lead over those beyond 15° shrinks, and the detail's
    mean eccentricity (the eccentricities weighed by each triangle's levels above the coarsest drawn) grows.

    (The number of triangles at the finest level is no measure of this: the prior lowers the visibility
    expected at the POI, and from a σ of a few degrees no triangle is at level 5 any more.)"""
    view = still_view(default_screen)
    near, lead, detail_ecc = [], [], []
    for prior in [(0.0, 0.0), (5.0, 4.0), (10.0, 7.0), (20.0, 15.0)]:
        levels, info = _levels(terrain_scene, view, "hybrid", change_share=share, gaze_prior_deg=prior)
        ecc = info["eccentricity_deg"]
        seen = np.isfinite(ecc)                              # in the frustum (the culled are level 0, ecc NaN)
        ecc, drawn = ecc[seen], levels[seen].astype(np.float64)
        near.append(drawn[ecc < 2].mean())
        lead.append(drawn[ecc < 2].mean() - drawn[ecc > 15].mean())
        above = drawn - drawn.min()
        detail_ecc.append(float((above * ecc).sum() / above.sum()))
    assert np.all(np.diff(near) < 0), near
    # The lead shrinks as the prior widens to the viewer model's size; at a σ of 20° (beyond it) the far
    # triangles' expected visibility is no longer monotone in the prior, but the lead stays below head-only's.
    assert np.all(np.diff(lead[:3]) < 0) and lead[-1] < lead[0], lead
    assert np.all(np.diff(detail_ecc) > 0), detail_ecc


# ---------------------------------------------------------------------------
# the command line
# ---------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.usefixtures("gl_context")
def test_render_takes_the_prior_and_records_the_one_in_use(tmp_path):
    stats = tmp_path / "s.json"
    assert cli.main(["render", "--gaze-prior", "1,2", "--size", "64,36", "--out", str(tmp_path / "a.png"),
                     "--stats", str(stats), "-q"]) == 0
    assert json.loads(stats.read_text())["gaze_prior_deg"] == [1.0, 2.0]
    # not given: the mode's own (hybrid's; 0,0 for a head-only mode)
    assert cli.main(["render", "--mode", "hybrid", "--size", "64,36", "--out", str(tmp_path / "b.png"),
                     "--stats", str(stats), "-q"]) == 0
    assert json.loads(stats.read_text())["gaze_prior_deg"] == list(GAZE_PRIOR_DEG)
    assert cli.main(["render", "--mode", "csf", "--size", "64,36", "--out", str(tmp_path / "c.png"),
                     "--stats", str(stats), "-q"]) == 0
    assert json.loads(stats.read_text())["gaze_prior_deg"] == [0.0, 0.0]


@pytest.mark.parametrize("value", ["-1,2", "1", "a,b", "50,1", "1,2,3", "nan,1", "inf,1", ""])
def test_a_bad_prior_is_refused_naming_the_option(tmp_path, capsys, value):
    with pytest.raises(SystemExit) as stop:
        cli.main(["render", "--gaze-prior", value, "--out", str(tmp_path / "x.png")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    # one line: the error (no usage block before it)
    errors = [line for line in err if ": error:" in line]
    assert errors == [err[-1]] and "--gaze-prior" in err[-1] and f"0..{MAX_GAZE_PRIOR_DEG:g}" in err[-1], err
    assert not (tmp_path / "x.png").exists()


def test_the_parser_bounds_the_prior_as_the_selector_does():
    from headplod import argtypes
    from headplod.plod import select

    assert argtypes.MAX_GAZE_PRIOR_DEG == select.MAX_GAZE_PRIOR_DEG
    assert argtypes.gaze_prior(f"{select.MAX_GAZE_PRIOR_DEG:g},0") == (select.MAX_GAZE_PRIOR_DEG, 0.0)
    assert argtypes.gaze_prior("-0,1.5") == (0.0, 1.5)


@pytest.mark.parametrize("argv", [["render", "--out", "x.png"], ["demo", "--headless"], ["bench", "plod"]],
                         ids=["render", "demo", "bench-plod"])
def test_every_command_that_builds_plod_frames_passes_the_prior_to_the_selector(argv):
    from headplod.render.command import selection_options

    parser = cli.build_parser()
    given = selection_options(parser.parse_args(argv + ["--gaze-prior", "4.5,0"]))
    assert SelectorConfig(mode="csf", **given).gaze_prior == (4.5, 0.0)
    absent = selection_options(parser.parse_args(argv))
    assert "gaze_prior_deg" not in absent                    # SelectorConfig's None: the mode's own
    assert SelectorConfig(mode="hybrid", **absent).gaze_prior == GAZE_PRIOR_DEG
