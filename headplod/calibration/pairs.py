"""The image pairs of a calibration folder: which left image goes with which right one."""

from __future__ import annotations

import re
from pathlib import Path

from .. import io

#: Fewest usable pairs :func:`calibrate_stereo` accepts.
MIN_PAIRS = 6
#: File name endings :func:`find_pairs` takes as images (case-insensitive).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _images_in(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                  key=lambda p: _natural_key(p.name))


def _list(names: list[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "")


_SIDE_NAME = re.compile(r"^(left|right)[_\-.]?(.*)$", re.IGNORECASE)


def find_pairs(folder: str | Path) -> list[tuple[str, Path, Path]]:
    """The stereo pairs of a calibration folder.

    Two layouts are recognised:

    - ``left/`` and ``right/`` subfolders holding images with the same
      names (the extension may differ): ``left/07.png`` + ``right/07.png``;
      the pair's name is the file's stem.
    - side by side, as OpenCV's samples: ``left07.jpg`` + ``right07.jpg``
      (also ``left_07``, ``Left-07``); the name is what follows the side.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    list of (name, left_path, right_path), in natural order of the names.

    Raises
    ------
    headplod.io.ContractError
        The folder does not exist, holds no pairs, or has images without a
        partner (all of them listed).
    """
    root = Path(folder)
    if not root.exists():
        raise io.ContractError(f"{root}: folder not found. Hint: give the folder of the calibration "
                               "image pairs", root)
    if not root.is_dir():
        raise io.ContractError(f"{root}: is a file, expected a folder of calibration image pairs", root)
    hint = ("expected left/ and right/ subfolders with images of the same names (left/00.png, "
            "right/00.png, ...) or side-by-side files leftNN.png and rightNN.png")
    sub_l, sub_r = root / "left", root / "right"
    if sub_l.is_dir() or sub_r.is_dir():
        if not (sub_l.is_dir() and sub_r.is_dir()):
            have, missing = (sub_l, sub_r) if sub_l.is_dir() else (sub_r, sub_l)
            raise io.ContractError(f"{root}: has {have.name}/ but no {missing.name}/ subfolder. "
                                   f"Hint: {hint}", root)
        left = {p.stem: p for p in _images_in(sub_l)}
        right = {p.stem: p for p in _images_in(sub_r)}
        where = (f"{sub_l}", f"{sub_r}")
    else:
        left, right = {}, {}
        for p in _images_in(root):
            m = _SIDE_NAME.match(p.stem)
            if m:
                (left if m.group(1).lower() == "left" else right)[m.group(2)] = p
        where = (f"{root}/left*", f"{root}/right*")
    if not left and not right:
        raise io.ContractError(f"{root}: no calibration images found. Hint: {hint} "
                               f"(image types: {', '.join(IMAGE_EXTENSIONS)})", root)
    only_l = sorted(set(left) - set(right), key=_natural_key)
    only_r = sorted(set(right) - set(left), key=_natural_key)
    if only_l or only_r:
        parts = []
        if only_l:
            parts.append(f"{len(only_l)} left image(s) without a right one: "
                         f"{_list([left[k].name for k in only_l])}")
        if only_r:
            parts.append(f"{len(only_r)} right image(s) without a left one: "
                         f"{_list([right[k].name for k in only_r])}")
        raise io.ContractError(
            f"{root}: unmatched images; " + "; ".join(parts)
            + f". Hint: every image in {where[0]} needs a partner of the same name in {where[1]}; "
            "delete or rename the odd ones", root)
    names = sorted(left, key=_natural_key)
    return [(n, left[n], right[n]) for n in names]

