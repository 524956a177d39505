"""Tracking stages: detect → identify → geometry → pose → uncertainty, and the rig's online refinement.

The stages still live at the package's top level until the restructuring
(issue 12) moves them here; new tracking code starts here.
"""
