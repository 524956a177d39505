"""Shared fixtures."""
import pytest

from headplod import io
from headplod.capture.synthetic import ensure_dataset


@pytest.fixture(scope="session")
def synth(tmp_path_factory):
    """Render (once per session) a synthetic preset into a temporary cache; returns an io.Dataset."""
    root = tmp_path_factory.mktemp("synthetic")

    def make(preset, frames, **options):
        return io.Dataset(ensure_dataset(preset, frames=frames, root=root, quiet=True, **options))
    return make
