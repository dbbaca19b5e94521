"""Scenes and tools that the tests, the benchmarks and the figure scripts share: particle lattices
(:mod:`~fracture_gs.testing.lattice`), small solver scenes of the fragment partition
(:mod:`~fracture_gs.testing.fragment_scenes`) and a headless browser that drives the viewer
(:mod:`~fracture_gs.testing.headless_browser`). Nothing in the package's commands imports them."""
