"""Stereo calibration of the two cameras from board images (``headplod calibrate``).

The board (:mod:`.board`), a folder's pairs (:mod:`.pairs`), the solve (:mod:`.calibrate`), advice while
capturing (:mod:`.guide`), the report (:mod:`.report`) and the command (:mod:`.command`).
"""
