"""Tracking stages: detect → identify → geometry → pose → uncertainty, and the rig's online refinement.

- :mod:`.detect`: marker blobs in one IR image.
- :mod:`.identify`: which blob is which marker.
- :mod:`.geometry`: stereo geometry and the pose estimators.
- :mod:`.tracker`: the stages together, two images in, a verified pose out.
- :mod:`.uncertainty`: the covariance of the viewing direction.
- :mod:`.rig_refine`: the rig's error model and online refinement.
- :mod:`.filters`: smoothing of the pose (One Euro, :mod:`headplod.filters`).
- :mod:`.evaluate`: accuracy of tracked poses against a dataset's truth.
"""
