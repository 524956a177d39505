"""The paper-conditions run (``headplod bench paper``): its pose jitter and its statistics."""
import numpy as np
import pytest

from headplod.bench.harness import poi_disc
from headplod.bench.image_metrics import psnr_db
from headplod.bench.paper_tables import JitteredPoses, PaperTablesConfig
from headplod.demo.loop import ReplayPoses
from headplod.demo import loop as lp
from headplod.plod.view import poi_direction
from headplod.render.still import default_head


def test_jitter_turns_the_viewing_direction_by_its_sigma_and_says_so():
    screen = lp.default_screen()
    eye = default_head(screen)
    centre = np.array(screen.size_px, dtype=np.float64) / 2
    cov = np.diag([0.002, 0.003])
    poses = [lp.Pose(k / 30, True, eye, centre, cov) for k in range(400)]
    jittered = JitteredPoses(ReplayPoses(poses, screen), noise_deg=0.5, seed=1)
    out = [jittered.read() for _ in poses]
    assert jittered.read() is None
    d0 = poi_direction(screen, eye, centre)
    angles = np.array([np.degrees(np.arccos(np.clip(poi_direction(screen, eye, p.poi_px) @ d0, -1, 1)))
                       for p in out])
    # The angle between two directions with independent N(0, σ²) offsets per axis is Rayleigh(σ).
    assert np.sqrt(np.mean(angles ** 2) / 2) == pytest.approx(0.5, rel=0.1)
    np.testing.assert_allclose(out[0].cov_deg2, cov + 0.25 * np.eye(2))
    assert all(p.eye_mm is eye for p in out)


def test_jitter_leaves_failed_poses_alone():
    screen = lp.default_screen()
    lost = lp.Pose(0.0, False, reason="markers hidden")

    class Once(lp.PoseSource):                   # gives the very object (ReplayPoses gives copies)
        name = "once"

        def read(self):
            return lost

    source = Once()
    source.screen = screen
    assert JitteredPoses(source, noise_deg=1.0).read() is lost


def test_disc_psnr_sees_only_the_disc():       # the paper tables' PSNR within the disc about the POI
    def disc_psnr_db(image, reference, centre_px, radius_px):
        return psnr_db(image, reference, poi_disc(reference.shape, centre_px, radius_px))

    ref = np.zeros((100, 200, 3), np.uint8)
    img = ref.copy()
    img[:, 150:] = 255                                   # outside a 20 px disc about pixel (50, 50)'s centre
    assert disc_psnr_db(img, ref, (50.5, 50.5), 20) == float("inf")
    img[50, 50] = 10
    assert disc_psnr_db(img, ref, (50.5, 50.5), 20) == pytest.approx(
        10 * np.log10(255 ** 2 / (3 * 100 / (3 * np.count_nonzero(
            (np.arange(200)[None] - 50) ** 2 + (np.arange(100)[:, None] - 50) ** 2 <= 400)))), rel=1e-9)


@pytest.mark.parametrize("bad", [{"frames": 2}, {"warmup": 60}, {"viewpoints": ("moon",)},
                                 {"conditions": ()}, {"noise_deg": float("nan")}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError, match="PaperTablesConfig"):
        PaperTablesConfig(**bad)
