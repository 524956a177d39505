"""The live stage: the one per-frame loop over any frame source, and its outputs.

- :mod:`.loop`: tracking a frame source frame by frame (``headplod track``), and
  the pose record of a frame.
- :mod:`.opentrack`: opentrack's UDP protocol (the six values and their datagram);
  :mod:`.udp`: the socket that sends them; :mod:`.status`: the live status line.
- :mod:`.command`: ``headplod track``'s arguments and run.
"""
