"""The demo window's keys: one table, :data:`KEYMAP`; the window's actions and every key help are made from it.

It imports neither moderngl-window nor the renderer, so the window, the HUD
and ``headplod demo --help`` share it.
"""
from __future__ import annotations

__all__ = ["DEMO_MODES", "KEYMAP", "action_for_key", "key_help"]

#: Criteria the demo switches between (keys 1-8; 1 the default criterion).
DEMO_MODES = ("hybrid", "change", "csf", "gp", "acuity", "sse", "distance", "full")

#: Key → action. Keys are single characters (digits, lower-case letters) or "escape".
KEYMAP = {
    **{str(i + 1): ("mode", m) for i, m in enumerate(DEMO_MODES)},
    "n": ("uncertainty", "none"),
    "f": ("uncertainty", "fixed"),
    "a": ("uncertainty", "adaptive"),
    "s": ("uncertainty", "smoothed"),
    "v": ("view_mode", "shaded"),
    "w": ("view_mode", "wire"),
    "l": ("view_mode", "levels"),
    "c": ("viewpoint", "next"),
    "h": ("hud", "toggle"),
    "escape": ("quit", None),
    "q": ("quit", None),
}


def action_for_key(name: str):
    """The action of a key, or None.

    Parameters
    ----------
    name : str
        ``"1"``-``"8"``, a letter (either case) or ``"escape"``.

    Returns
    -------
    tuple (setting, value) or None
        ``("mode", "hybrid")`` … ``("mode", "full")`` for 1-8,
        ``("uncertainty", ...)`` for N/F/A/S, ``("view_mode", ...)`` for
        V (shaded), W (wire), L (levels), ``("hud", "toggle")`` for H,
        ``("viewpoint", "next")`` for C, ``("quit", None)`` for Esc and Q;
        :meth:`DemoLoop.apply` takes it.
    """
    return KEYMAP.get(str(name).lower())

#: How the key help names each setting of :data:`KEYMAP`.
_SETTING_NAMES = {"mode": "criterion", "uncertainty": "scenario", "view_mode": "view", "viewpoint": "viewpoint",
                  "hud": "hud", "quit": "quit"}


def _key_label(key: str) -> str:
    return "Esc" if key == "escape" else key.upper()


def _keys_label(keys: list[str]) -> str:
    """``1-7`` for a run of consecutive digits, else the keys joined by ``/`` (``N/F/A/S``, ``Esc/Q``)."""
    if len(keys) > 2 and all(k.isdigit() for k in keys) and \
            [int(k) for k in keys] == list(range(int(keys[0]), int(keys[0]) + len(keys))):
        return f"{keys[0]}-{keys[-1]}"
    return "/".join(_key_label(k) for k in keys)


def key_help(values=("mode",), sep: str = "  ") -> str:
    """The keys of :data:`KEYMAP` as one line of help, one group per setting, in the table's order.

    Parameters
    ----------
    values : iterable of str
        Settings whose values are listed after their keys, in brackets
        (``1-8 criterion (hybrid change csf gp acuity sse distance full)``).
    sep : str
        Between the groups.
    """
    groups: dict[str, list[tuple[str, object]]] = {}
    for key, (setting, value) in KEYMAP.items():
        groups.setdefault(setting, []).append((key, value))
    parts = []
    for setting, entries in groups.items():
        text = f"{_keys_label([k for k, _ in entries])} {_SETTING_NAMES.get(setting, setting)}"
        if setting in values:
            text += " (" + " ".join(str(v) for _, v in entries) + ")"
        parts.append(text)
    return sep.join(parts)
