"""Tracking stages: detect → identify → geometry → pose → uncertainty, and the rig's online refinement.

- :mod:`.detect`: marker blobs in one IR image.
- :mod:`.identify`: which blob is which marker.
- :mod:`.geometry`: stereo geometry and the pose estimators.
- :mod:`.tracker`: the parts composed, two images in, a verified pose out, and the
  state machine; its parts: :mod:`.tracker_config` (settings), :mod:`.frame_checks`
  (images and times), :mod:`.detection` (blobs, and the locked markers re-measured),
  :mod:`.acquire` (identification), :mod:`.lock` (the markers of a frame and the
  lock on them), :mod:`.pose_fit` (the fit), :mod:`.rig_check` (checks against the
  images and the rig), :mod:`.rolling_shutter` (readout compensation),
  :mod:`.covariance` (the covariance of V's stage), :mod:`.tracker_rig` (the rig
  in use, its refinement and bootstrap), :mod:`.motion` (the head's motion).
- :mod:`.uncertainty`: the covariance of the viewing direction.
- :mod:`.rig_refine`: the rig's online refinement, composed of
  :mod:`.rig_estimator` (the estimate and its chunk updates),
  :mod:`.rig_schedule` (the updates spread over frames) and :mod:`.rig_report`
  (its text and status); :mod:`.rig_refine_config`
  (settings), :mod:`.rig_state` (the refined parameters and their derivatives),
  :mod:`.rig_priors` (the error model and priors), :mod:`.rig_frames` (the
  frames of a chunk and their velocities), :mod:`.rig_solve` (a chunk's solve).
- :mod:`.motion`: the head's recent motion.
- :mod:`.filters`: smoothing of the pose (One Euro, :mod:`headplod.filters`).
- :mod:`.evaluate`: accuracy of tracked poses against a dataset's truth.
"""
