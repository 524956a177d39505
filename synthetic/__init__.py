"""Synthetic IR stereo renderer and scene presets for headplod.

Independent of the ``headplod`` package (it never imports it), so that the
tracker's tests compare against data made by separate code.

Modules
-------
conventions : the contract (marker model, head axes, file writers).
setups      : rigs and screen geometry (default, wide HD).
render      : image formation (``render_pair``).
scenes      : trajectories and presets (``make_scene``, ``PRESETS``).
dataset     : contract dataset folders (``write_dataset``).

Command line: ``python -m synthetic render PRESET OUT_DIR [--frames N] [--seed S] [-q]`` (:mod:`.cli`; also ``headplod synth``).
"""
import importlib

# Lazy attribute access (PEP 562), so that ``python -m synthetic.setups`` does
# not import its own module twice.
_WHERE = {
    "DEFAULT_MARKERS_MM": "conventions",
    "DEFAULT_DIAMETER_MM": "conventions",
    "viewing_axes": "conventions",
    "head_rotation": "conventions",
    "Setup": "setups",
    "default_setup": "setups",
    "wide_hd_setup": "setups",
    "RenderOptions": "render",
    "Lamp": "render",
    "render_pair": "render",
    "Scene": "scenes",
    "make_scene": "scenes",
    "PRESETS": "scenes",
    "write_dataset": "dataset",
}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_MARKERS_MM",
    "DEFAULT_DIAMETER_MM",
    "viewing_axes",
    "head_rotation",
    "Setup",
    "default_setup",
    "wide_hd_setup",
    "RenderOptions",
    "Lamp",
    "render_pair",
    "Scene",
    "make_scene",
    "PRESETS",
    "write_dataset",
]
