"""Perceptual level of detail, pure numpy: contrast sensitivity, level selection, the terrain and its meshes."""
