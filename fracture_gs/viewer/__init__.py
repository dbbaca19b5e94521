"""Interactive browser viewer (viser) of simulations and trained models: ``view.py``.

:mod:`~fracture_gs.viewer.sources` prepares frames with the renderer's code path,
:mod:`~fracture_gs.viewer.splats` converts them to viser's splats,
:mod:`~fracture_gs.viewer.cache` keeps them (LRU, background thread), and
:mod:`~fracture_gs.viewer.app` serves them with the GUI.
"""
