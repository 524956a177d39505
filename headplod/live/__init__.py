"""The live stage: the one per-frame loop over any frame source, and its outputs.

- :mod:`.loop`: tracking a frame source frame by frame (``headplod track``).
- :mod:`.pipeline`: pose records and progress for a dataset run.
- :mod:`.output`: opentrack's UDP protocol and the live status line.
"""
