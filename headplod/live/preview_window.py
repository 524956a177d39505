"""``headplod preview``'s window: the preview's picture (:func:`~headplod.live.preview_picture.render`, the
same picture ``--out`` writes) as one texture in a moderngl-window window (the pyglet backend, as the demo's),
with the keys of :class:`~headplod.live.preview_controls.Controls`.

The preview pulls frames from its source and calls :meth:`PreviewWindow.show` for each, so the window is
driven frame by frame (no moderngl-window event loop): draw, swap, handle the events that came. moderngl-window
is imported only when a window opens, so this module imports without it and without a display.

The picture is drawn 1:1 when the window keeps the size it was opened with (it may be resized: the picture is
then scaled to fill it). ``snapshot`` reads the window's own framebuffer back after each drawing (the test of
the window checks that picture against the truth).
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from .. import io
from .preview_controls import Controls

__all__ = ["PreviewWindow", "WindowUnavailable", "window_problem"]

_VERTEX = """
#version 330
out vec2 v_uv;
void main() {                       // one triangle over the viewport; v_uv (0, 0) bottom left, (1, 1) top right
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    v_uv = p;
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
"""
_FRAGMENT = """
#version 330
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;
void main() {                       // the picture is BGR with row 0 at the top
    f_color = vec4(texture(u_image, vec2(v_uv.x, 1.0 - v_uv.y)).bgr, 1.0);
}
"""
#: While a finished replay's last picture is held, the window looks for events this often, s.
HOLD_PERIOD_S = 1.0 / 30.0


class WindowUnavailable(RuntimeError):
    """No window can be opened here (no moderngl-window, no display, no OpenGL 3.3); the message says why."""


def window_problem(environ=None) -> str | None:
    """Why no window can be opened here, found without opening one (no display, no moderngl-window), or None."""
    environ = os.environ if environ is None else environ
    if sys.platform.startswith("linux") and not (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")):
        return "there is no display (DISPLAY is not set)"
    try:
        import moderngl_window  # noqa: F401 -- optional: only a window needs it
    except ImportError:
        return "moderngl-window is not installed (setup.sh installs it)"
    return None


def _key_names(keys) -> dict:
    """moderngl-window key codes -> the names :meth:`Controls.press` takes (lower case; shift makes upper)."""
    names = {getattr(keys, ch.upper()): ch for ch in "abcdefghijklmnopqrstuvwxyz"
             if getattr(keys, ch.upper(), None) is not None}
    if getattr(keys, "ESCAPE", None) is not None:
        names[keys.ESCAPE] = "escape"
    return names


class PreviewWindow:
    """A window showing pictures, (H, W, 3) uint8 BGR, with the preview's keys.

    Parameters
    ----------
    size : (width, height)
        The picture's size, px (the window opens at it).
    controls : Controls
        What the keys do.
    snapshot : str or Path, optional
        Write the window's framebuffer, as last drawn, to this PNG when the window closes.
    backend : str
        moderngl-window's window backend.

    Raises
    ------
    WindowUnavailable
    """

    def __init__(self, size: tuple[int, int], controls: Controls, snapshot=None, backend: str = "pyglet"):
        try:
            import moderngl_window as mglw   # optional: only a window needs it
            self.wnd = mglw.get_local_window_cls(backend)(title="headplod preview", size=tuple(size), resizable=True,
                                                          vsync=False, gl_version=(3, 3), aspect_ratio=None)
        except Exception as exc:   # no display, no GL driver: pyglet raises its own types
            where = f" on DISPLAY {os.environ['DISPLAY']}" if os.environ.get("DISPLAY") else ""
            raise WindowUnavailable(f"cannot open a window{where} ({type(exc).__name__}: "
                                    f"{' '.join(str(exc).split())})") from None
        mglw.activate_context(window=self.wnd)
        self.ctx, self.controls, self.snapshot_path = self.wnd.ctx, controls, snapshot
        self.size = tuple(size)
        self.texture = self.ctx.texture(self.size, 3, alignment=1)
        self.quad = self.ctx.vertex_array(self.ctx.program(vertex_shader=_VERTEX, fragment_shader=_FRAGMENT), [])
        self.names = _key_names(self.wnd.keys)
        self.messages: list[str] = []        # what the keys did, for the command to print
        self.heard = 0                       # keys that did something
        self.held = False                    # the last picture is held (:meth:`hold`)
        self.closed_by: str | None = None    # the key that closed the window
        self.framebuffer: np.ndarray | None = None
        self.wnd.key_event_func = self.on_key

    def on_key(self, key, action, modifiers) -> None:
        """moderngl-window's key callback: a press goes to :meth:`Controls.press`."""
        if action != self.wnd.keys.ACTION_PRESS or key not in self.names:
            return
        name = self.names[key]
        if modifiers.shift and len(name) == 1:
            name = name.upper()
        result = self.controls.press(name)
        if result.message:
            self.messages.append(result.message)
            self.heard += 1
        if result.close:
            self.closed_by = name
            self.wnd.close()

    def show(self, k: int, picture: np.ndarray) -> bool:
        """Draw ``picture`` (frame ``k``) and handle the events that came; False once the window is closing."""
        if self.wnd.is_closing:
            return False
        h, w = picture.shape[:2]
        if (w, h) != self.texture.size:       # the first picture of cameras of a size no rig said
            self.texture.release()
            self.texture = self.ctx.texture((w, h), 3, alignment=1)
            if k == 0:
                self.wnd.size = (w, h)
        self.texture.write(np.ascontiguousarray(picture).tobytes())
        self._draw()
        return not self.wnd.is_closing

    def _draw(self) -> None:
        self.wnd.use()
        self.ctx.clear(0.0, 0.0, 0.0)
        self.texture.use(0)
        self.quad.render(vertices=3)
        if self.snapshot_path is not None:
            w, h = self.wnd.buffer_size
            rgb = np.frombuffer(self.wnd.fbo.read(viewport=(0, 0, w, h), components=3, alignment=1), np.uint8)
            self.framebuffer = np.ascontiguousarray(rgb.reshape(h, w, 3)[::-1, :, ::-1])   # rows top down, BGR
        self.wnd.swap_buffers()              # the pyglet backend handles the events here
        title = self.controls.title() + (" [the recording ended]" if self.held else "")
        if not self.wnd.is_closing and self.wnd.title != title:
            # The values and keys in the title once a picture is up: a person (and a test's xdotool) then
            # knows that the keys are heard.
            self.wnd.title = title

    def hold(self, repaint=None, sleep=time.sleep) -> None:
        """Keep the last picture up until the window is closed (a key, or its close button); ``repaint()``, when
        given, draws it again after a key that did something (a new threshold), (H, W, 3) uint8 BGR."""
        heard, self.held = self.heard, True
        while not self.wnd.is_closing:
            if repaint is not None and self.heard != heard:
                heard = self.heard
                self.texture.write(np.ascontiguousarray(repaint()).tobytes())
            self._draw()
            sleep(HOLD_PERIOD_S)

    def close(self) -> None:
        """Close the window; write the snapshot when one was asked for (OSError when it cannot be written)."""
        try:
            if self.snapshot_path is not None and self.framebuffer is not None:
                io.write_atomically(self.snapshot_path, lambda name: io.write_image(name, self.framebuffer),
                                    suffix=".png")
        finally:
            self.wnd.destroy()
