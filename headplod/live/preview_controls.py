"""The keys of ``headplod preview``'s window: exposure, gain and threshold changed live, and written to the
config file.

:class:`Controls` owns the values; :meth:`Controls.press` takes a key's name (``"e"``, ``"E"``, ``"escape"``,
as :func:`key_name` gives it) and returns what happened, a :class:`KeyResult`. The window calls it from its
key handler; a test calls it directly, with a fake camera. The cameras are anything with
``control(name) -> float | None`` and ``set_controls(exposure=, gain=)`` (:class:`~headplod.capture.v4l2.V4L2StereoSource`);
None for a replay, whose exposure and gain are recorded.

Keys: ``q`` or Esc close; ``e``/``E`` exposure down/up, ``g``/``G`` gain down/up (live cameras only),
``t``/``T`` threshold down/up (from the adaptive one the frame used, then fixed), ``a`` the adaptive threshold
again, ``w`` writes exposure, gain and threshold into the config file.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

from ..io import TomlKeysError, set_toml_keys

__all__ = ["ControlSettings", "Controls", "KeyResult", "KEYS_HELP"]

#: One line naming the keys (the window's title ends with it).
KEYS_HELP = "q close, e/E exposure, g/G gain, t/T threshold, a adaptive, w write config"


@dataclass(frozen=True)
class ControlSettings:
    """How far one key press moves a value.

    Attributes
    ----------
    exposure_factor : float
        ``E`` multiplies the exposure by this, ``e`` divides (camera units, UVC 100 µs: a ratio suits a range
        of 1 to 5000).
    gain_step : float
        ``g``/``G`` change the gain by this, camera units.
    threshold_step_dn : float
        ``t``/``T`` change the threshold by this, DN.
    threshold_range_dn : (float, float)
        The threshold stays strictly inside this range, DN (as ``--threshold`` takes it).
    """

    exposure_factor: float = 1.25
    gain_step: float = 1.0
    threshold_step_dn: float = 5.0
    threshold_range_dn: tuple = (0.0, 255.0)


class KeyResult(NamedTuple):
    """What a key did: ``close`` the window; ``message`` one line for the person (None: the key means nothing)."""

    close: bool
    message: str | None


class Controls:
    """Exposure, gain (camera units) and threshold (DN, None: adaptive) as the keys set them.

    Parameters
    ----------
    camera : object or None
        Live cameras (``control``, ``set_controls``); None for a replay.
    exposure, gain : float or None
        The values asked on the command line (None: the camera's own, read on the first press).
    threshold_dn : float or None
        The detection threshold, DN; None: adaptive.
    set_threshold : callable(float or None)
        Called with the new threshold (the previewer's detection takes it from the next frame).
    measured_threshold : callable() -> float or None
        The threshold the last frame's adaptive detection used, DN (where ``t``/``T`` start from).
    config_path : callable() -> Path
        The config file ``w`` writes.
    settings : ControlSettings
    """

    def __init__(self, camera=None, exposure: float | None = None, gain: float | None = None,
                 threshold_dn: float | None = None, set_threshold: Callable = lambda dn: None,
                 measured_threshold: Callable = lambda: None, config_path: Callable = lambda: Path("headplod.toml"),
                 settings: ControlSettings = ControlSettings()):
        self.camera, self.exposure, self.gain, self.threshold_dn = camera, exposure, gain, threshold_dn
        self._set_threshold, self._measured = set_threshold, measured_threshold
        self._config_path, self.settings = config_path, settings

    def press(self, key: str) -> KeyResult:
        """Act on the key named ``key`` (``"e"``, ``"E"``, ``"escape"``, ...)."""
        if key in ("q", "Q", "escape"):
            return KeyResult(True, None)
        if key in ("e", "E"):
            return self._camera_step("exposure", up=key == "E")
        if key in ("g", "G"):
            return self._camera_step("gain", up=key == "G")
        if key in ("t", "T"):
            return self._threshold_step(up=key == "T")
        if key == "a":
            self.threshold_dn = None
            self._set_threshold(None)
            return KeyResult(False, "threshold: adaptive")
        if key == "w":
            return self._write()
        return KeyResult(False, None)

    def _camera_step(self, name: str, up: bool) -> KeyResult:
        if self.camera is None:
            return KeyResult(False, f"{name}: live cameras only (a recording's {name} is what it was)")
        value = getattr(self, name)
        if value is None:
            value = self.camera.control(name)
        if value is None:
            return KeyResult(False, f"{name}: the camera reports none; give --{name} to start from")
        s = self.settings
        if name == "exposure":
            new = round(value * s.exposure_factor if up else value / s.exposure_factor)
            if new == round(value):            # a small exposure: at least one unit a press
                new = round(value) + (1 if up else -1)
            new = float(max(1, new))
        else:
            new = max(0.0, value + (s.gain_step if up else -s.gain_step))
        report = self.camera.set_controls(**{name: new})
        setattr(self, name, new)
        actual = [x.actual for settings in report.values() for x in settings if x.name == name]
        shown = ", ".join("-" if a is None else f"{a:g}" for a in actual)
        return KeyResult(False, f"{name} {new:g} (cameras report {shown or 'nothing'})")

    def _threshold_step(self, up: bool) -> KeyResult:
        current = self.threshold_dn if self.threshold_dn is not None else self._measured()
        if current is None or not math.isfinite(current):
            return KeyResult(False, "threshold: no frame measured yet")
        low, high = self.settings.threshold_range_dn
        step = self.settings.threshold_step_dn
        new = float(min(max(round(current) + (step if up else -step), low + 1), high - 1))
        self.threshold_dn = new
        self._set_threshold(new)
        return KeyResult(False, f"threshold {new:g} DN")

    def _write(self) -> KeyResult:
        values = {"threshold": "adaptive" if self.threshold_dn is None else self.threshold_dn}
        for name in ("exposure", "gain"):
            if getattr(self, name) is not None:
                values[name] = getattr(self, name)
        path = self._config_path()
        try:
            set_toml_keys(path, values)
        except (TomlKeysError, OSError) as exc:
            return KeyResult(False, f"config not written: {exc}")
        shown = ", ".join(f"{k} {v if isinstance(v, str) else format(v, 'g')}" for k, v in values.items())
        return KeyResult(False, f"wrote {shown} to {path}")

    def title(self) -> str:
        """The values on one line (the window's title shows it)."""
        def show(v, unit=""):
            return "auto" if v is None else f"{v:g}{unit}"
        threshold = "adaptive" if self.threshold_dn is None else f"{self.threshold_dn:g} DN"
        live = f"exposure {show(self.exposure)}  gain {show(self.gain)}  " if self.camera is not None else ""
        return f"headplod preview: {live}threshold {threshold}  ({KEYS_HELP})"
