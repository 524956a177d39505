"""Read-backs the tests need from the renderers, kept out of the product (they reach into its GL objects).

- :func:`triangle_samples`: every triangle a :class:`TessellationRenderer` generates, as height-grid samples;
- :func:`layer_image`: one layer of a :class:`FoveatedRenderer`'s last frame at its own resolution.
"""
import numpy as np

from headplod.render.context import moderngl


def triangle_samples(r, view, proj, model, cv, *, mode: str = "csf", capacity: int = 1 << 20) -> np.ndarray:
    """Every triangle ``r`` (a TessellationRenderer) generates for ``cv``, as its three vertices' samples
    (T, 3, 2) int64 (column, row); GL 4.3."""
    ranges = r._draw_ranges(view, proj, model, cv, mode, None)
    kind = "samples_tree" if r._tree_frame else "samples"
    prog = r._program(kind)
    r._set_uniforms(prog, view, proj, model, cv, mode, None)
    r._remember(cv)
    buf = r.ctx.buffer(np.array([0, capacity, 0, 0], np.uint32).tobytes() + bytes(24 * capacity))
    try:
        buf.bind_to_storage_buffer(1)
        r._bind()
        r._fbo.use()                  # (not under RASTERIZER_DISCARD: see TessellationRenderer._levels_pass)
        for first, count in ranges:
            r._vaos[kind].render(moderngl.PATCHES, vertices=count, first=first)
        r.ctx.memory_barrier()
        raw = buf.read()
    finally:
        buf.release()
    count = int(np.frombuffer(raw[:4], np.uint32)[0])
    if count > capacity:
        raise ValueError(f"triangle_samples: {count} triangles, more than capacity={capacity}")
    return np.frombuffer(raw[16:16 + 24 * count], np.float32).reshape(count, 3, 2).round().astype(np.int64)


def layer_image(fov, k: int) -> np.ndarray:
    """Layer ``k`` of ``fov``'s (a FoveatedRenderer) last frame as drawn, (h_k, w_k, 3) uint8 RGB, top row
    first, at its own resolution (outside the layer's rectangle: whatever was there before)."""
    from headplod.render.foveate import _read_rect

    if not 0 <= k < fov.config.max_layers:
        raise ValueError(f"layer_image: k must be in 0..{fov.config.max_layers - 1}, got {k}")
    fbo = fov._targets[k][1]
    return _read_rect(fbo, (0, 0, *fbo.size), {})
