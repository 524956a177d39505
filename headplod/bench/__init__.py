"""Benchmarks: accuracy against speed for every method (``headplod bench ...``).

- :mod:`.track`: the pose estimators on synthetic sets; :mod:`.rig`: the imperfect-rig sets.
- :mod:`.uncertainty`: the covariance of V (NEES, stability, cost).
- :mod:`.live`: the live pipeline's rate and latency on a replayed recording.
- :mod:`.plod`: speed against image error of every LOD mode.
- :mod:`.command`: ``headplod bench``'s arguments and dispatch.

Accuracy against a dataset's truth is :mod:`headplod.tracking.evaluate` (``headplod track`` reports it too).
"""
