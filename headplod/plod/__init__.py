"""Perceptual level of detail, pure numpy: the view conditioning, the criteria, level selection, the terrain, its meshes.

- :mod:`.view`: the one view-conditioning step per frame (:class:`~.view.ConditionedView`).
- :mod:`.csf`, :mod:`.perception`: the contrast sensitivity and the papers' perceptual rules;
  :mod:`.criteria`: every mode's level for a piece of terrain, once, with the hierarchies' bounds;
  :mod:`.cull`: the frustum tests.
- :mod:`.select`: levels per base triangle (:class:`~.select.LevelSelector`, settings
  :class:`~.select.SelectorConfig`); :mod:`.patches`, :mod:`.patch_tree`: the GPU back end's patches and
  their quadtree; :mod:`.raymask`: Murphy & Duchowski's ray mask.
- :mod:`.shading`: the one light and the displayed contrast; :mod:`.contrast`: the paper's read-back.
- :mod:`.terrain`, :mod:`.terrain_file`: the terrain and a person's own file; :mod:`.mesh_base`,
  :mod:`.mesh`, :mod:`.lazy_mesh`, :mod:`.mesh_cases`: the crack-free adaptive meshes; :mod:`.export`.
"""
