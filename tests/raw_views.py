"""Raw views for a level selector, conditioned the way the frame step conditions them.

A selector (:class:`headplod.plod.select.LevelSelector`, the bench's ``QuadtreeSelector``) takes only a
:class:`headplod.plod.view.ConditionedView`. Tests that feed it raw :class:`headplod.plod.view.View` s wrap it
in :class:`RawViews` (``from raw_views import RawViews``, as they import ``conftest``).
"""
from headplod.plod.view import ViewConditioner


class RawViews:
    """``selector`` fed raw views: each frame's :class:`View` goes through one :class:`ViewConditioner` of the
    selector's own screen and :class:`SelectorConfig` (what :class:`headplod.render.frame.FrameStep` does with
    its settings' selection config), then to ``selector.select``.

    The conditioner keeps its filters across calls, one call per frame; :meth:`reset` forgets them with the
    selector's own state.
    """

    def __init__(self, selector):
        self.selector = selector
        self.conditioner = ViewConditioner(selector.screen, selector.config)

    def select(self, view):
        """``selector.select`` of ``view`` (a raw View) conditioned: levels (F,) int and the info dict."""
        return self.selector.select(self.conditioner(view))

    def reset(self) -> None:
        """Forget the conditioner's filters and the selector's last frame and hysteresis."""
        self.conditioner.reset()
        self.selector.reset()
