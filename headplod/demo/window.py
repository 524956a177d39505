"""The demo window: a thin moderngl-window app over :class:`headplod.demo.loop.DemoLoop`.

moderngl-window is imported only when a window is opened, so this module
(and its key mapping, :func:`action_for_key`, from :mod:`.keys`) imports
without it and without a display.

Each frame the loop renders the terrain offscreen on the window's own GL
context, composes the HUD with OpenCV, and the window draws the image as
one texture on a full-window triangle (a 1280x720 RGB upload is ~3 MB, a few
ms; the same pixels as the headless PNGs).
"""
from __future__ import annotations

import sys

import numpy as np

from ..progress import note
from ..render.command import raymask_config, selection_options
from ..render.frame import default_mode
from ..render import TerrainRenderer
from ..render.gl import FULLSCREEN_VERTEX_SHADER
from ..render.scene_command import mesh_options
from .keys import action_for_key
from .loop import DemoLoop
from .poses import make_poses


_FRAGMENT = """
#version 330
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(texture(u_image, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, 1.0);  // image row 0 is the top
}
"""


def _key_names(keys) -> dict:
    """moderngl-window key codes → the names :func:`action_for_key` takes."""
    names = {}
    for i in range(1, 10):
        code = getattr(keys, f"NUMBER_{i}", None)
        if code is not None:
            names[code] = str(i)
    for ch in "abcdefghijklmnopqrstuvwxyz":
        code = getattr(keys, ch.upper(), None)
        if code is not None:
            names[code] = ch
    if getattr(keys, "ESCAPE", None) is not None:
        names[keys.ESCAPE] = "escape"
    names.pop("undefined", None)
    return names


def make_window_class():
    """The WindowConfig subclass (imports moderngl_window)."""
    import moderngl_window as mglw  # optional: only a window needs it (headless runs and tests do not)

    class DemoWindow(mglw.WindowConfig):
        gl_version = (3, 3)
        title = "headplod demo: head-coupled perceptual LOD"
        window_size = (1280, 720)
        aspect_ratio = None
        resizable = True
        vsync = False

        def __init__(self, demo_args=None, **kwargs):
            super().__init__(**kwargs)
            args = demo_args
            self.poses = make_poses(args)
            note("building the terrain mesh ...")
            scene = mesh_options(args).build(self.poses.screen, getattr(args, "terrain_loaded", None))
            size = tuple(args.size)
            mode = args.mode or default_mode(getattr(args, "backend", "mesh"))
            self.loop = DemoLoop(scene, self.poses, TerrainRenderer(self.ctx, size=size), mode=mode,
                                 uncertainty=args.uncertainty, viewpoint=args.viewpoint, view_mode=args.view,
                                 saccade_deg_s=args.saccade_deg_s, growth_deg2_per_s=args.growth,
                                 foveate=getattr(args, "foveate", False), backend=getattr(args, "backend", "mesh"),
                                 selector_options=selection_options(args), raymask=raymask_config(args))
            self.texture = self.ctx.texture(size, 3)
            self.program = self.ctx.program(vertex_shader=FULLSCREEN_VERTEX_SHADER, fragment_shader=_FRAGMENT)
            self.quad = self.ctx.vertex_array(self.program, [])
            self.names = _key_names(self.wnd.keys)
            self.mouse = hasattr(self.poses, "set_poi")

        def on_render(self, time, frame_time):
            result = self.loop.step()
            if result is None:
                self.wnd.close()
                return
            self.texture.write(np.ascontiguousarray(result.image).tobytes())
            self.wnd.use()
            self.ctx.clear(0.0, 0.0, 0.0)
            self.texture.use(0)
            self.quad.render(vertices=3)

        def on_key_event(self, key, action, modifiers):
            if action != self.wnd.keys.ACTION_PRESS:
                return
            if not self.loop.apply(action_for_key(self.names.get(key, ""))):
                self.wnd.close()

        def on_mouse_position_event(self, x, y, dx, dy):
            if self.mouse:
                w, h = self.wnd.size
                sw, sh = self.loop.screen.size_px
                self.poses.set_poi((x * sw / max(w, 1), y * sh / max(h, 1)))

        def on_close(self):
            self.poses.close()

    return DemoWindow


def run_window(args, window: str | None = None) -> int:
    """Open the window and run until it is closed; the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        ``headplod demo`` options.
    window : str, optional
        moderngl-window backend ("pyglet", "glfw", "headless", ...);
        default: moderngl-window's default (pyglet).
    """
    try:
        import moderngl_window as mglw  # optional: only a window needs it (headless runs and tests do not)
    except ImportError:
        print("headplod demo: the window needs moderngl-window ('pip install moderngl-window'); "
              "'headplod demo --headless' runs without it", file=sys.stderr)
        return 1
    cls = make_window_class()
    try:
        window_cls = mglw.get_local_window_cls(window)
        wnd = window_cls(title=cls.title, size=tuple(args.size), resizable=True, vsync=False, gl_version=(3, 3),
                         aspect_ratio=None)
    except Exception as exc:   # no display, no GL driver: pyglet and glfw raise their own types
        print(f"headplod demo: cannot open a window ({type(exc).__name__}: {exc}); "
              "without a display, run 'headplod demo --headless'", file=sys.stderr)
        return 1
    mglw.activate_context(window=wnd)
    config = cls(demo_args=args, ctx=wnd.ctx, wnd=wnd, timer=mglw.Timer())
    wnd.config = config       # the public setter; it assigns the callbacks again, as __init__ did (idempotent)
    mglw.run_window_config_instance(config)
    return 0
