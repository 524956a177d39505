"""A headless OpenGL context through EGL (Mesa llvmpipe works; a GPU when there is one)."""
from __future__ import annotations

import os

try:  # the pure-numpy parts (projection, scene transform, overlay) work without it
    import moderngl
except ImportError as _exc:  # pragma: no cover - moderngl is a hard dependency
    moderngl = None
    _MODERNGL_IMPORT_ERROR: ImportError | None = _exc
else:
    _MODERNGL_IMPORT_ERROR = None

#: Debian/Ubuntu packages that provide headless EGL with Mesa's llvmpipe.
EGL_PACKAGES = "libegl1 libgl1-mesa-dri"


# --------------------------------------------------------------------------
# context
# --------------------------------------------------------------------------


class GLContextError(RuntimeError):
    """No OpenGL context could be made (no EGL, no Mesa driver, a broken vendor file, too old a version).

    One line that says what to check; a command reports it as a failed run (exit status 1).
    """


def create_context(require: int = 330) -> "moderngl.Context":
    """A standalone, headless OpenGL context through EGL (Mesa llvmpipe or a GPU).

    The one place the commands make an offscreen context (``render``, the
    headless ``demo``, the benchmarks, ``doctor``'s check).

    Parameters
    ----------
    require : int
        Minimum OpenGL version code (330 = OpenGL 3.3 core, enough for the
        shaders here).

    Returns
    -------
    moderngl.Context
        Current on the calling thread; release it with ``ctx.release()``.

    Raises
    ------
    GLContextError
        When moderngl is not installed, or EGL / a Mesa driver is missing,
        broken or too old; the message (one line) says what failed, then
        after ``. Hint:`` what to check.
    """
    if moderngl is None:
        raise GLContextError(
            f"the OpenGL context could not be made: moderngl is not importable ({_MODERNGL_IMPORT_ERROR}); "
            "install it with 'pip install moderngl' (setup.sh does)"
        )
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=require)
    except Exception as exc:  # glcontext raises plain Exception subclasses
        raise GLContextError(
            f"the OpenGL {require // 100}.{require % 100 // 10} context could not be made through EGL "
            f"({' '.join(str(exc).split()) or type(exc).__name__}). Hint: check {_what_to_check()}"
        ) from None
    return ctx


def _what_to_check() -> str:
    """What to check when EGL gives no context: a vendor file the environment names but that is missing, then
    the packages setup.sh installs, then a GPU's own libEGL."""
    named = [f for v in ("__EGL_VENDOR_LIBRARY_FILENAMES",) for f in os.environ.get(v, "").split(":") if f]
    missing = [f for f in named if not os.path.isfile(f)]
    first = (f"__EGL_VENDOR_LIBRARY_FILENAMES, which names {', '.join(missing)} (no such file); then "
             if missing else "")
    return (f"{first}that EGL and Mesa's software driver are installed (setup.sh installs them: "
            f"apt-get install {EGL_PACKAGES}), or on a GPU machine the vendor's libEGL and access to /dev/dri "
            "('headplod doctor' checks EGL)")
