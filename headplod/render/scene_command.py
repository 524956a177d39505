"""The commands' scene options: the terrain (``--terrain``, ``--spacing-m``, ``--height-scale``) and its mesh
(``--max-level``, ``--lazy``, ``--cache-mb``).

``headplod render``, ``headplod demo`` and ``headplod bench plod`` add them
with :func:`add_terrain_arguments` and :func:`add_mesh_arguments` and turn
them into typed values once: a Terrain (or the built-in scene's None) with
:func:`terrain_for_command`, which prints the reader's notes and the one-line
reason of a failure and gives the exit status, and a
:class:`headplod.render.still.MeshOptions` with :func:`mesh_options`. The
reading itself is :mod:`headplod.plod.terrain_file`'s and the scene
:mod:`headplod.render.still`'s (typed values in, typed errors out).
"""
from __future__ import annotations

import argparse
import sys

from ..plod.lazy_mesh import DEFAULT_CACHE_BYTES
from ..plod.mesh_base import FULL_MAX_LEVEL
from ..plod.terrain_file import (TerrainFileOptions, TerrainUsageError, check_spacing, check_terrain_path,
                                 terrain_from_file)

from .frame import CAPABILITIES
from .still import DEFAULT_MAX_LEVEL, TABLE_MAX_LEVEL, MeshOptions

__all__ = ["add_terrain_arguments", "terrain_options", "terrain_from_args", "terrain_for_command",
           "add_mesh_arguments", "mesh_options", "mesh_options_problem"]


def _spacing_arg(text: str) -> tuple[float, float]:
    """argparse type of ``--spacing-m``: ``D`` or ``DX,DY``, metres, each in the accepted range."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (1, 2):
        raise argparse.ArgumentTypeError(f"expected D or DX,DY in metres, got {text!r}")
    try:
        for v in values:
            check_spacing("the spacing", v)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return (values[0], values[-1])


def _height_scale_arg(text: str) -> float:
    try:
        return TerrainFileOptions(height_scale=float(text)).height_scale
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).replace("height_scale", "the height scale")) from None


def add_terrain_arguments(parser) -> None:
    """Add ``--terrain``, ``--spacing-m`` and ``--height-scale`` to a parser or argument group."""
    parser.add_argument("--terrain", metavar="FILE",
                        help="your own terrain instead of the built-in one: a GeoTIFF DEM (.tif; spacing from its "
                             "georeferencing), a 16-bit PNG height map (.png) or a 2-D array (.npy; both row 0 "
                             "north, with --spacing-m); no-data samples are filled, and said so")
    parser.add_argument("--spacing-m", type=_spacing_arg, metavar="D|DX,DY",
                        help="--terrain: sample spacing east[,north], metres (required for .png and .npy; "
                             "overrides a GeoTIFF's georeferencing)")
    parser.add_argument("--height-scale", type=_height_scale_arg, metavar="M_PER_UNIT",
                        help="--terrain: metres per stored height unit (default 1)")


def terrain_options(args) -> tuple[str | None, TerrainFileOptions]:
    """(``--terrain``'s path or None, the :class:`TerrainFileOptions` of ``--spacing-m`` and ``--height-scale``).

    Raises :class:`TerrainUsageError` for ``--spacing-m``/``--height-scale`` without ``--terrain``.
    """
    path = getattr(args, "terrain", None)
    spacing, scale = getattr(args, "spacing_m", None), getattr(args, "height_scale", None)
    if path is None:
        given = [name for name, v in (("--spacing-m", spacing), ("--height-scale", scale)) if v is not None]
        if given:
            raise TerrainUsageError(f"{' and '.join(given)} only apply with --terrain FILE")
        return None, TerrainFileOptions()
    return path, TerrainFileOptions(spacing_m=spacing, height_scale=1.0 if scale is None else scale)


def terrain_from_args(args, err=None):
    """The Terrain of ``args.terrain`` (None without it: the built-in scene), notes printed to ``err``
    (default: standard error as it is at the call).

    Raises
    ------
    TerrainUsageError
        ``--spacing-m``/``--height-scale`` without ``--terrain``, an unknown
        ending, a PNG or ``.npy`` without ``--spacing-m`` (exit status 2).
    TerrainFileError
        A missing or unusable file (exit status 1).
    """
    path, options = terrain_options(args)
    if path is None:
        return None
    err = err or sys.stderr
    check_terrain_path(path, options)
    print(f"terrain: reading {path}", file=err)
    terrain, grid = terrain_from_file(path, options)
    for note in grid.notes:
        print(f"terrain: {note}", file=err)
    print(f"terrain: {grid.describe()}", file=err)
    return terrain


def terrain_for_command(args, program: str, err=None):
    """:func:`terrain_from_args` for a command: (Terrain or None, None), or (None, exit status) with the
    one-line reason printed as ``program: ...`` (2 for options that cannot work together, 1 for a bad file)."""
    err = err or sys.stderr
    try:
        return terrain_from_args(args, err), None
    except TerrainUsageError as exc:
        print(f"{program}: {exc}", file=err)
        return None, 2
    except ValueError as exc:
        print(f"{program}: --terrain {exc}", file=err)
        return None, 1


def add_mesh_arguments(parser) -> None:
    """Add ``--max-level``, ``--lazy`` and ``--cache-mb`` (the scene's mesh) to a parser or argument group.

    Their values are checked by :func:`mesh_options_problem` (one line, exit status 2, before anything is
    written), not by argparse (whose usage message is many lines).
    """
    parser.add_argument("--max-level", default=None, metavar="N",
                        help=f"finest PLOD level, 1..8 (default {DEFAULT_MAX_LEVEL}: the 32x32 base to 1025x1025 "
                             "samples, 2.1M triangles at full detail); above 5 the mesh is made lazily (only the "
                             "pieces a frame draws, in a bounded cache) and the terrain is sampled at "
                             "32*2^N+1 per side (4097 at 7), so a fine --terrain DEM shows its own detail near "
                             "the POI; the built-in terrain's synthetic detail is refined to match")
    parser.add_argument("--lazy", action="store_true",
                        help="use the lazy mesh at --max-level 5 or lower too (the same triangles as the default "
                             "whole-table mesh)")
    parser.add_argument("--cache-mb", default=None, metavar="MB",
                        help=f"lazy mesh: byte budget of its piece cache, MB (default {DEFAULT_CACHE_BYTES >> 20}; "
                             "the pieces of a frame beyond it are made again when next needed)")


def mesh_options(args) -> MeshOptions:
    """The :class:`MeshOptions` of :func:`add_mesh_arguments`'s options (``argparse.ArgumentTypeError``
    naming the option for a bad value); ``args`` is left as it is."""
    from ..argtypes import cache_mb, max_level

    values = {}
    for name, option, parse in (("max_level", "--max-level", max_level), ("cache_mb", "--cache-mb", cache_mb)):
        value = getattr(args, name, None)
        if isinstance(value, str):
            try:
                value = parse(value)
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentTypeError(f"{option}: {exc}") from None
        values[name] = value
    level, mb = values["max_level"], values["cache_mb"]
    return MeshOptions(DEFAULT_MAX_LEVEL if level is None else int(level), bool(getattr(args, "lazy", False)),
                       MeshOptions.cache_mb if mb is None else float(mb))


def mesh_options_problem(args, backend: str, mode: str) -> str | None:
    """Why the mesh options cannot work with the ``backend`` and ``mode`` a command will draw (one line), or None.

    - ``--cache-mb`` without the lazy mesh: it has no cache.
    - a back end that cannot work over the lazy mesh (:attr:`BackendCapabilities.lazy_mesh`; the ``raymask`` one
      casts rays against the height field of the whole ``full`` mesh, which the lazy mesh never holds) with it.
    - ``full`` above :data:`FULL_MAX_LEVEL`: 134 M triangles at level 8 do not fit (~3 GB a frame); nor does
      ``render --compare full``'s reference frame there.

    Also the values themselves: ``--max-level`` a whole number in 1..8, ``--cache-mb`` in 1..65536.
    """
    try:
        options = mesh_options(args)
    except argparse.ArgumentTypeError as exc:
        return str(exc)
    level, lazy = options.max_level, options.lazy
    if getattr(args, "cache_mb", None) is not None and not lazy:
        return "--cache-mb applies to the lazy mesh only (--max-level above 5, or --lazy)"
    if lazy and not CAPABILITIES[backend].lazy_mesh:
        return (f"--backend {backend} casts rays against the whole full-detail mesh, which the lazy mesh does not "
                f"keep; use --max-level {TABLE_MAX_LEVEL} or lower without --lazy")
    if mode == "full" and level > FULL_MAX_LEVEL:
        return (f"--mode full at --max-level {level} would draw {2048 * 4 ** level:,} triangles (about "
                f"{2048 * 4 ** level * 24 / 2 ** 30:.1f} GB a frame); use --max-level {FULL_MAX_LEVEL} or lower, "
                "or a PLOD mode such as csf")
    if getattr(args, "compare", None) == "full" and level > FULL_MAX_LEVEL:
        return (f"--compare full at --max-level {level} would draw full's {2048 * 4 ** level:,} triangles (about "
                f"{2048 * 4 ** level * 24 / 2 ** 30:.1f} GB a frame), which do not fit; compare at --max-level "
                f"{FULL_MAX_LEVEL} or lower")
    return None
