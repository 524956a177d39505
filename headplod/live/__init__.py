"""The live stage: the one per-frame loop over any frame source, and its outputs.

- :mod:`.loop`: tracking a frame source frame by frame (``headplod track``), and
  the pose record of a frame.
- :mod:`.pipeline`: the same loop over a dataset folder.
- :mod:`.output`: opentrack's UDP protocol and the live status line.
- :mod:`.command`: ``headplod track``'s arguments and run.
"""
