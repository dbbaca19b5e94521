"""Synthetic multi-view datasets of the paper's objects (docs/training.md, Synthetic datasets).

``python -m fracture_gs.data.synthetic --object {teapot,bowl,table,ficus,all} --out DIR``
renders a Blender / NeRF-synthetic dataset (docs/file_formats.md §1) with Mitsuba 3 (``scalar_rgb``; an
optional dependency: ``pip install mitsuba==3.9.1``; nothing else in the package needs it).

Objects (procedural, built as signed distance fields and meshed by marching cubes, so every
mesh is closed/watertight and consistently oriented; ``--grid`` cells along the longest side):

* ``teapot`` — the Utah teapot from Newell's public 32-patch / 306-point Bézier table,
  tessellated here. The open places of the patch set (lid-rim ring, spout opening, tube ends)
  are closed by flat caps and the enclosed volume is filled: a **solid** teapot with the lid
  glued shut and the spout plugged (what a reconstruction from images can recover). One part.
* ``bowl`` — surface of revolution of a quarter-ellipse profile with a 0.08-thick wall (rounded
  rim) and a foot ring. One part.
* ``table`` — rounded top slab (part 0 "top") on four tapered legs (part 1 "legs").
* ``ficus`` — a standard-trained potted plant: terracotta pot filled with soil (part 0 "pot"),
  trunk, branches and twigs (part 1 "branches"), ~100 folded elliptic leaves (part 2 "leaves").
  Leaves only grow above the crown bottom so box / half-space rules can separate the parts;
  twig segments inside the crown are therefore labelled (and coloured) as leaves.

Object coordinates = dataset world coordinates: z up, the bounding-box centre at the origin,
uniformly scaled so the farthest surface point lies on the unit sphere. ``parts.json`` holds the
part rules in these coordinates and the normalisation (``center``, ``scale`` from the natural
units). Each part has its own look: a solid (3D procedural) texture as per-vertex colour and a
principled BSDF roughness.

Views: ``--n-train`` (100) cameras on a Fibonacci spiral and ``--n-test`` (20) random ones, all
at distance 4.0311 looking at the origin with elevations in [-30°, +72°], horizontal field of
view 0.6911 rad (NeRF-synthetic values), ``--width`` x ``--height`` (400 x 400). The scene is
lit by a dim uniform sky (hidden from the camera) and two directional lights fixed in the world.
PNGs are RGBA with straight alpha = pixel coverage (box filter, multi-jittered samples), colour
in sRGB, background white. ``transform_matrix`` is camera-to-world in OpenGL axes; Mitsuba's
sensor frame (x left, y up, z forward) is ``c2w_gl @ diag(-1, 1, -1, 1)``.

``gt_mesh.ply`` is the rendered mesh (for evaluation only: training must not read it).
"""
