"""A headless OpenGL context through EGL (Mesa llvmpipe works; a GPU when there is one)."""
from __future__ import annotations

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


def create_context(require: int = 330) -> "moderngl.Context":
    """A standalone, headless OpenGL context through EGL (Mesa llvmpipe or a GPU).

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
    RuntimeError
        When moderngl is not installed, or EGL / a Mesa driver is missing or
        too old; the message names the Debian packages to install.
    """
    if moderngl is None:
        raise RuntimeError(
            f"moderngl is not importable ({_MODERNGL_IMPORT_ERROR}); "
            "install it with 'pip install moderngl'"
        )
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=require)
    except Exception as exc:  # glcontext raises plain Exception subclasses
        raise RuntimeError(
            f"cannot create a headless OpenGL {require // 100}.{require % 100 // 10} "
            f"context through EGL: {type(exc).__name__}: {exc}. "
            f"Hint: install EGL and Mesa's software driver (Debian/Ubuntu: "
            f"'apt-get install {EGL_PACKAGES}'); on a GPU machine check that the "
            "vendor's libEGL is installed and that /dev/dri is accessible"
        ) from exc
    return ctx
