"""Image files through memory: OpenCV's Python binding is never handed a path.

The binding turns a ``str`` argument into UTF-8 and, for a path that does not encode (a name with a
byte that is not UTF-8, ``b'caf\\xe9'``, which Python holds as ``'caf\\udce9'``; or any non-ASCII name
under ``LC_ALL=C`` without Python's UTF-8 mode), crashes the process: ``cv2.imread``, ``cv2.imwrite``,
``cv2.haveImageWriter``, ``cv2.FileStorage`` and ``cv2.VideoCapture`` alike. So Python reads and writes
the files, whatever their names, and OpenCV only decodes and encodes bytes (:func:`read_image`,
:func:`write_image`; the YAML files go through ``cv2.FILE_STORAGE_MEMORY`` in :mod:`._storage`).

What OpenCV can only open by its name (a video file, a camera device) goes through :func:`opencv_name`:
the name's bytes as UTF-8 text, or :class:`UnnamablePath` (the path shown safely) when they are not.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

__all__ = ["UnnamablePath", "read_image", "decode_image", "encode_image", "write_image", "writes_images", "opencv_name",
           "shown_path"]


class UnnamablePath(ValueError):
    """A path OpenCV's binding cannot be given (its name is not UTF-8 text); the message shows it safely."""


def shown_path(path) -> str:
    """``path`` as printable text: bytes that are not UTF-8 as ``\\xe9`` escapes (the name stays readable)."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def read_image(path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """The image in the file ``path`` as OpenCV decodes it with ``flags`` (``cv2.imread``'s result), or None
    when its bytes are not an image OpenCV decodes (an empty file too).

    Raises
    ------
    OSError
        When the file cannot be read.
    """
    return decode_image(Path(path).read_bytes(), flags)


def decode_image(data: bytes, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """The image OpenCV decodes from a file's bytes ``data`` with ``flags``, or None when they are not an image
    it decodes (no bytes too)."""
    if not data:
        return None
    return cv2.imdecode(np.frombuffer(data, np.uint8), flags)


def writes_images(ending: str) -> bool:
    """Whether OpenCV can encode an image as a file ending ``ending`` (``".png"``, ``".jpg"``; any case)."""
    if not ending or not ending.isascii() or not ending.startswith("."):
        return False                              # a name OpenCV's binding cannot take is no ending it knows
    return bool(cv2.haveImageWriter("image" + ending))


def encode_image(image: np.ndarray, ending: str, params: Sequence[int] = ()) -> bytes:
    """The bytes of the file ``ending`` (``".png"``, ...) holding ``image`` (``cv2.imwrite``'s layout: gray
    (H, W) or BGR (H, W, 3), uint8 or uint16), with ``cv2.imwrite``'s ``params``.

    Raises
    ------
    ValueError
        When OpenCV cannot encode it so (an ending it does not know, a depth the format does not hold).
    """
    if not writes_images(ending):
        raise ValueError(f"OpenCV cannot write images ending {ending or '(no ending)'!r}")
    try:
        ok, data = cv2.imencode(ending, image, list(params))
    except cv2.error as exc:
        ok, data = False, exc
    if not ok:
        raise ValueError(f"OpenCV cannot encode this {getattr(image, 'dtype', '')} image "
                         f"{getattr(image, 'shape', '')} as {ending}")
    return data.tobytes()


def write_image(path, image: np.ndarray, params: Sequence[int] = (), ending: str | None = None) -> None:
    """Write ``image`` to the file ``path`` in the format of ``ending`` (default: the path's own), as
    ``cv2.imwrite`` would, whatever the path's name.

    Raises
    ------
    ValueError
        When OpenCV cannot encode the image so (:func:`encode_image`).
    OSError
        When the file cannot be written.
    """
    data = encode_image(image, Path(path).suffix if ending is None else ending, params)
    with open(path, "wb") as f:
        f.write(data)


def opencv_name(path, what: str = "file", library: str = "OpenCV") -> str:
    """``path`` as the text OpenCV (or another C ``library`` that takes UTF-8 names: GDAL) opens a file by
    (``cv2.VideoCapture``): the name's bytes read as UTF-8, which the library turns back into the same bytes
    (so a UTF-8 name works under ``LC_ALL=C`` too).

    Raises
    ------
    UnnamablePath
        When the name's bytes are not UTF-8 text (``b'caf\\xe9'``); the message shows the path with
        ``\\xNN`` escapes and says what to do.
    """
    raw = os.fsencode(path)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UnnamablePath(f"{shown_path(raw)}: this name is not UTF-8 text, and {library} opens a {what} by its "
                            "name (it cannot open this one); rename the file or its folder with UTF-8 "
                            "characters") from None
