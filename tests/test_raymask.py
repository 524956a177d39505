"""Murphy & Duchowski's hybrid rendering (issue 13, ``raymask``): the ray mask's density follows the CSF,
the uncertainty widens its full-density region to the 2σ ellipse, silhouette quads sit where the terrain
meets the sky, a still view gives identical frames, and the inset matches ``full``."""
import math

import cv2
import numpy as np
import pytest

from headplod.plod.csf import gp_cutoff_cpd
from headplod.plod.raymask import (RayMaskConfig, build_ray_mask, height_grid, pixel_offsets_deg, radii_deg,
                                   spacing_px, spacing_thresholds_deg)
from headplod.plod.view import head_axes

PPD = 25.2267           # the default view's px/deg at 1280x720 (render.still.px_per_deg_at)


def _csf_spacing(ecc_deg, ppd, contrast=1.0, max_n=17):
    """The spacing the CSF allows, written out: the largest n with 2 f_c(e) <= ppd / n (1..max_n)."""
    f = gp_cutoff_cpd(contrast, ecc_deg)
    return np.clip(np.floor(ppd / (2 * f)), 1, max_n).astype(int)


@pytest.mark.parametrize("contrast", [1.0, 0.3])
def test_ring_spacing_and_counts_follow_the_csf(contrast):
    cfg = RayMaskConfig(contrast=contrast, inset_deg=0.0)
    r_fill, rings, steps = radii_deg(PPD, 40.0, cfg)
    # The fill ends where the CSF first allows 2 px: f_c(r_fill) = ppd / 4.
    assert gp_cutoff_cpd(contrast, r_fill) == pytest.approx(PPD / 4, rel=1e-9)
    # Every radial step is the CSF's spacing at the ring it starts from (to the threshold's rounding).
    gaps_px = np.diff(rings) * PPD
    np.testing.assert_allclose(gaps_px, steps[:-1], atol=1e-9)
    e = rings[:-1] + 1e-9
    np.testing.assert_array_equal(steps[:-1], _csf_spacing(e, PPD, contrast))
    # Counts per band: the rings between T_n and T_n+1 are (T_n+1 - T_n) / n, to one ring at each end.
    t = spacing_thresholds_deg(PPD, cfg)
    for n in range(2, 6):
        if t[n + 1] > 40.0:
            break
        count = np.count_nonzero((rings >= t[n]) & (rings < t[n + 1]))
        assert abs(count - (t[n + 1] - t[n]) * PPD / n) <= 1.0
    assert np.array_equal(spacing_px(rings[:-1] + 1e-9, PPD, cfg), steps[:-1])


def test_the_mask_samples_at_least_as_densely_as_the_csf_asks(default_screen):
    from headplod.render.still import default_head

    head = default_head(default_screen)
    poi = np.array(default_screen.size_px) / 2
    mask = build_ray_mask(default_screen, head, poi, (1280, 720), PPD)
    # Angles seen from the eye: the spacing is n px at the POI's px/deg, i.e. n / ppd degrees everywhere.
    xy = (mask.samples_px[mask.n_fill:] + 0.5) * 1.5                   # image px -> screen px (1920 / 1280)
    rays = default_screen.pixel_to_world(xy) - head
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)

    def angle_deg(a, b):
        return np.degrees(2 * np.arcsin(np.linalg.norm(rays[a] - rays[b], axis=1) / 2))
    # Along a ring, neighbours are no farther apart than the ring's radial spacing (the angular step is
    # the outermost ring's), so the density is at least 1 / n² everywhere; across rings, the spacing is n.
    q = mask.quads - mask.n_fill
    n_deg = mask.spacing_of[mask.n_fill:][q[:, 0]] / PPD
    along, across = angle_deg(q[:, 1], q[:, 0]), angle_deg(q[:, 3], q[:, 0])
    assert np.all(along <= n_deg * 1.001)
    np.testing.assert_allclose(across, n_deg, rtol=1e-3)
    # The fill is every pixel out to r_fill: about π r² pixels (the ring is ~1 px wider per degree off-axis).
    r_px = mask.r_fill_deg * PPD
    assert mask.n_fill == pytest.approx(math.pi * r_px ** 2, rel=0.05)
    # The inset setting widens the fill beyond the CSF's when it is larger.
    wide = build_ray_mask(default_screen, head, poi, (1280, 720), PPD, config=RayMaskConfig(inset_deg=30.0))
    assert wide.r_fill_deg == 15.0 and wide.n_fill > mask.n_fill


@pytest.mark.slow
def test_the_uncertainty_widens_the_full_density_region_to_the_2_sigma_ellipse(default_screen):
    from headplod.render.still import default_head

    head = default_head(default_screen)
    poi = np.array(default_screen.size_px) / 2
    size = (1280, 720)
    cfg = RayMaskConfig(contrast=0.05, inset_deg=2.0)          # a small fill: the ellipse dominates
    cov = np.diag([1.5 ** 2, 3.0 ** 2])                        # σ (φ, θ) = (1.5°, 3°)
    plain = build_ray_mask(default_screen, head, poi, size, PPD, None, cfg)
    wide = build_ray_mask(default_screen, head, poi, size, PPD, cov, cfg)
    yy, xx = np.mgrid[0:size[1], 0:size[0]]
    pix = np.stack([xx.ravel(), yy.ravel()], -1).astype(float)
    off = pixel_offsets_deg(pix, default_screen, head, head_axes(default_screen, head, poi), size)
    m2 = np.einsum("ni,ij,nj->n", off, np.linalg.inv(cov), off)
    filled = np.zeros(len(pix), bool)
    filled[(wide.fill_px[:, 1] * size[0] + wide.fill_px[:, 0])] = True
    inside = m2 <= 4.0
    assert inside.sum() > 5000
    # The fill is exactly the pixels csf's shifted eccentricity puts within r_fill.
    from headplod.plod import perception as pc
    shifted_ecc = pc.eccentricity_deg(pc.uncertainty_shift(off, cov, "ellipse", 2.0))
    assert np.array_equal(filled, shifted_ecc <= wide.r_fill_deg)
    assert filled[inside].all()                                 # the whole 2σ ellipse is at full density
    # ... and the fill is the ellipse dilated by the fill radius: along θ (horizontal) it reaches
    # r_fill + 2σ_θ, along φ r_fill + 2σ_φ (to a pixel).
    row = filled.reshape(size[1], size[0])[360]
    col = filled.reshape(size[1], size[0])[:, 640]
    half_w = (np.count_nonzero(row) - 1) / 2 / PPD
    half_h = (np.count_nonzero(col) - 1) / 2 / PPD
    assert half_w == pytest.approx(plain.r_fill_deg + 6.0, abs=0.15)
    assert half_h == pytest.approx(plain.r_fill_deg + 3.0, abs=0.15)
    # The rings start beyond it: every ring sample's offset is outside the ellipse.
    ring_off = pixel_offsets_deg(wide.samples_px[wide.n_fill:], default_screen, head,
                                 head_axes(default_screen, head, poi), size)
    assert np.all(np.einsum("ni,ij,nj->n", ring_off, np.linalg.inv(cov), ring_off) > 4.0)


def test_settings_are_checked():
    for bad in (dict(inset_deg=31), dict(inset_deg=-1), dict(contrast=0), dict(csf_model="x"),
                dict(max_spacing_px=0), dict(max_spacing_px=2.5), dict(n_sigma=-1), dict(silhouettes="yes"),
                dict(depth_ratio=0)):
        with pytest.raises(ValueError, match="RayMaskConfig"):
            RayMaskConfig(**bad)
    # Kelly forms are accepted and give a spacing that widens outward too.
    t = spacing_thresholds_deg(PPD, RayMaskConfig(csf_model="kelly_scaled"))
    assert np.all(np.diff(t[2:][np.isfinite(t[2:])]) > 0)


@pytest.mark.slow
def test_the_height_field_is_the_full_mesh(terrain_scene):
    grid = height_grid(terrain_scene.mesh)
    assert grid.heights.shape == (1025, 1025)
    # full's triangle count is two per cell.
    assert 2 * 1024 * 1024 == terrain_scene.mesh.triangle_count(np.full(terrain_scene.mesh.n_faces, 5))
    z = terrain_scene.terrain.heights(grid.origin[0] + 10 * grid.cell[0], grid.origin[1] + 7 * grid.cell[1])
    assert float(grid.heights[7, 10]) == pytest.approx(float(np.asarray(z).ravel()[0]), abs=1e-3)


# ---------------------------------------------------------------------------- rendering (GL)

@pytest.fixture(scope="module")
def raymask_setup(gl_context, terrain_scene, default_screen):
    from headplod.render import TerrainRenderer
    from headplod.render.raymask import RayMaskRenderer

    size = (1280, 720)
    return {"full": TerrainRenderer(gl_context, size=size), "ray": RayMaskRenderer(gl_context, terrain_scene.mesh, size),
            "size": size}


@pytest.mark.slow
def test_the_inset_matches_full_and_a_still_view_repeats_exactly(raymask_setup, terrain_scene, default_screen):
    from headplod.render.image_metrics import psnr_db
    from headplod.plod.select import SelectorConfig
    from headplod.render.frame import FrameSettings
    from headplod.render.still import StillSettings, default_head, px_per_deg_at, render_still

    size = raymask_setup["size"]
    full, _ = render_still(StillSettings(FrameSettings("mesh", SelectorConfig(mode="full")), size=size),
                           default_screen, scene=terrain_scene, renderer=raymask_setup["full"])
    frames = [render_still(StillSettings(FrameSettings("raymask"), size=size), default_screen, scene=terrain_scene,
                           raymask_renderer=raymask_setup["ray"])[0] for _ in range(3)]
    assert all(np.array_equal(frames[0], f) for f in frames[1:])          # a still view: identical frames
    ppd = px_per_deg_at(default_screen, default_head(default_screen), size)
    yy, xx = np.mgrid[0:size[1], 0:size[0]]
    disc = np.hypot(xx - size[0] / 2, yy - size[1] / 2) <= 5 * ppd
    assert psnr_db(frames[-1], full, disc) >= 45.0
    assert psnr_db(frames[-1], full) >= 35.0


@pytest.mark.slow
def test_silhouette_quads_are_where_the_terrain_meets_the_sky(raymask_setup, terrain_scene, default_screen):
    from headplod.demo.viewpoints import place
    from headplod.render import off_axis_projection
    from headplod.render.still import default_head, px_per_deg_at

    size = raymask_setup["size"]
    scene = place(terrain_scene, "plains")
    head = default_head(default_screen)
    view, proj = off_axis_projection(head, default_screen, near_mm=50.0, far_mm=5000.0)
    r = raymask_setup["full"]
    scene.mesh.clear()
    positions, normals, levels = scene.mesh.update(np.full(scene.mesh.n_faces, 5))
    r.upload(positions, normals, levels)
    full = r.render(view, proj, scene.model)
    sky = np.all(full == np.round(np.array(r.background) * 255).astype(np.uint8), axis=2)
    # The truth: terrain pixels of full with a sky pixel beside them, and those sky pixels.
    edge = sky ^ cv2.erode(sky.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE
                           ).astype(bool)
    edge |= cv2.dilate(sky.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~sky
    rr = raymask_setup["ray"]
    poi = np.array(default_screen.size_px) / 2
    cfg = RayMaskConfig(contrast=0.3)                           # a small fill: more of the horizon in rings
    mask = rr.mask(default_screen, head, poi, px_per_deg_at(default_screen, head, size), None, cfg)
    image = rr.render(mask, view, proj, scene.model, cfg)
    sil = mask.quads[rr.last_silhouette_quads]
    polys = np.round(mask.samples_px[sil] * 16).astype(np.int32)           # 4 bits of sub-pixel
    covered = np.zeros(full.shape[:2], np.uint8)
    cv2.fillPoly(covered, list(polys), 1, lineType=cv2.LINE_8, shift=4)
    covered = cv2.dilate(covered, np.ones((3, 3), np.uint8)).astype(bool)
    fill = np.zeros_like(covered)
    fill[mask.fill_px[:, 1], mask.fill_px[:, 0]] = True
    ring_edge = edge & ~cv2.dilate(fill.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert ring_edge.sum() > 500                                 # the view has a long horizon in the rings
    assert covered[ring_edge].mean() >= 0.99                     # found wherever the truth has one
    # ... and the silhouette quads hold the truth's edge (or a nearer-ridge depth jump): each mixed quad does.
    hits = rr.last_hits[:, 3] > 0
    mixed = ~(hits[sil - mask.n_fill].all(axis=1))
    edge_u8 = cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8))
    corners = mask.samples_px[sil[mixed]]
    on_image = np.all((corners >= 0) & (corners <= np.array(size) - 1), axis=(1, 2))
    picked = corners[on_image][::max(1, on_image.sum() // 200)]   # about 200 of them (a loop: a test check)
    contains = np.array([cv2.fillPoly(np.zeros_like(edge_u8), [np.round(p * 16).astype(np.int32)], 1,
                                      shift=4)[edge_u8.astype(bool)].any() for p in picked])
    assert len(picked) > 50 and contains.mean() >= 0.98, corners[on_image][~contains][:3]
    # With silhouettes cast per pixel, the sky/terrain boundary is full's to a pixel.
    ours = np.all(image == np.round(np.array(r.background) * 255).astype(np.uint8), axis=2)
    assert (ours != sky)[ring_edge].mean() <= 0.02


@pytest.mark.slow
def test_render_command_draws_raymask_and_refuses_what_it_cannot(tmp_path, gl_context, capsys):
    import json

    from headplod.cli import main as cli_main

    out, stats = tmp_path / "ray.png", tmp_path / "ray.json"
    assert cli_main(["render", "--backend", "raymask", "--size", "320,180", "--inset-deg", "10", "--no-silhouettes",
                     "--out", str(out), "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    assert s["backend"] == "raymask" and s["raymask"]["inset_deg"] == 10 and s["raymask"]["silhouettes"] is False
    assert s["raymask"]["rays"] == s["raymask"]["fill_rays"] + s["raymask"]["ring_rays"]   # none per pixel
    assert 0 < s["raymask"]["rays"] < 320 * 180 * 2 and s["render_ms"] > 0
    assert out.stat().st_size > 1000
    assert cli_main(["render", "--backend", "raymask", "--inset-deg", "31", "--out", str(out)]) == 2
    assert cli_main(["render", "--backend", "raymask", "--foveate", "--out", str(out)]) == 2
    assert "does not take --foveate" in capsys.readouterr().err
