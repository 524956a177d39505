"""Reading and writing the files of the headplod contract.

This package is the one place where headplod reads and writes the files that
``docs/contract.md`` defines: the stereo rig (``rig.yaml``), the marker
model (``markers.yaml``), the screen (``screen.yaml``), a stereo dataset folder
(``left/``, ``right/``, ``times.csv``, ``truth.csv``, ``gaze_truth.csv``) and the pose records
(JSON Lines). Every public name is available here (``io.read_rig``,
``io.Dataset``, ...); the modules hold one kind of file each:

==============  ==========================================================
``_storage``    :class:`ContractError`, OpenCV FileStorage helpers, checks
                shared by several files
``rig``         ``rig.yaml``: :class:`Rig`, :func:`read_rig`, ...
``markers``     ``markers.yaml``: :class:`MarkerModel`, ...
``screen``      ``screen.yaml``: :class:`Screen`, ...
``tables``      ``times.csv``, ``truth.csv`` and ``gaze_truth.csv``
``dataset``     the dataset folder: :class:`Dataset`, :class:`Frame`
``poses``       pose records (JSON Lines): :func:`pose_record`, ...
``images``      image files through memory (:func:`read_image`,
                :func:`write_image`): OpenCV never sees a path
==============  ==========================================================

Conventions (from the contract)
-------------------------------
- Lengths in mm, times in s, image coordinates in px, angles in degrees in
  every file.
- Camera frame: OpenCV's (x right, y down, z forward). World frame: the left
  camera's frame. A point X in the world (left camera) frame is
  ``R @ X + T`` in the right camera frame.
- Glasses frame G: origin at P1, x toward P0, z out of the wearer's face,
  y = z x x.

Errors
------
Everything that is wrong with a file raises :class:`ContractError` (a
``ValueError``) whose message starts with the file's path, says what is wrong
as expected against actual, and usually ends with ``Hint: ...`` on how to fix
it. Frames of a dataset are the exception: a bad image never raises, it gives
a :class:`Frame` whose ``error`` says what is wrong, so that the other frames
can still be processed. Wrong values handed to a writer by code (NaN in a
pose, a non-rotation) are programming errors and raise ``ValueError``.
"""

from __future__ import annotations

from ._storage import (
    AXES_TOL_READ,
    AXES_TOL_WRITE,
    ContractError,
    ProgressiveOutput,
    read_storage,
    write_atomically,
    writing_storage,
)
from .dataset import DEFAULT_FPS, Dataset, Frame
from .images import UnnamablePath, decode_image, encode_image, opencv_name, read_image, shown_path, write_image, writes_images
from .markers import (
    MARKER_TOL_MM,
    VIEW_TRIANGLES,
    MarkerModel,
    default_marker_model,
    read_markers,
    write_markers,
)
from .poses import POSE_KEYS, PoseWriter, pose_record, read_poses
from .rig import (
    CALIBRATION_STD_KEYS,
    DIST_COEFF_COUNTS,
    MIN_BASELINE_MM,
    ROTATION_TOL,
    Rig,
    read_rig,
    rig_calibration_std,
    write_rig,
)
from .screen import Screen, ViewError, read_screen, write_screen
from .toml_keys import TomlKeysError, set_toml_keys
from .tables import (
    GAZE_TRUTH_COLUMNS,
    TRUTH_COLUMNS,
    GazeTruth,
    read_gaze_truth,
    read_times,
    read_truth,
    write_gaze_truth,
    write_times,
    write_truth,
)

__all__ = [
    "set_toml_keys", "TomlKeysError",
    "ContractError",
    "write_atomically",
    "ProgressiveOutput",
    "read_storage",
    "writing_storage",
    "read_image",
    "decode_image",
    "write_image",
    "encode_image",
    "writes_images",
    "opencv_name",
    "shown_path",
    "UnnamablePath",
    "Rig",
    "read_rig",
    "write_rig",
    "rig_calibration_std",
    "CALIBRATION_STD_KEYS",
    "MarkerModel",
    "default_marker_model",
    "read_markers",
    "write_markers",
    "Screen",
    "ViewError",
    "read_screen",
    "write_screen",
    "Frame",
    "Dataset",
    "read_truth",
    "write_truth",
    "GazeTruth",
    "read_gaze_truth",
    "write_gaze_truth",
    "read_times",
    "write_times",
    "pose_record",
    "PoseWriter",
    "read_poses",
    "POSE_KEYS",
    "TRUTH_COLUMNS",
    "GAZE_TRUTH_COLUMNS",
    "DEFAULT_FPS",
    # the contract's constants and the tolerances of the checks
    "VIEW_TRIANGLES",
    "DIST_COEFF_COUNTS",
    "ROTATION_TOL",
    "MIN_BASELINE_MM",
    "MARKER_TOL_MM",
    "AXES_TOL_WRITE",
    "AXES_TOL_READ",
]
