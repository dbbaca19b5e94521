"""Utah teapot (Newell 1975): the 32 bicubic Bézier patches, tessellated and made solid.
The control-point table (306 points, 32 patches of 4x4 1-based indices) is the public-domain
fact table of the teapot, typed in here; units are Newell's (height 3.15, z up, spout along +x).
The 32-patch set includes the bottom, so the body is closed below; the open places are

* the ring between the lid's lower edge (radius 1.3, z = 2.4) and the rim's inner edge
  (radius 1.4, z = 2.4) — closed by a flat annulus (the lid is treated as glued shut);
* the spout opening (a planar loop at z = 2.4) — closed by a flat cap (a plugged spout);
* the ends of the handle and the spout tubes, which are buried in (or touch) the body — closed
  by flat caps so each tube encloses a volume.

The resulting closed surface (patches + caps) is turned into a solid by
:func:`fracture_gs.data.synthetic.meshing.solid_sdf_from_surface_samples` (the teapot is
**solid**, not a thin shell: that is what a reconstruction from images recovers).
"""
from __future__ import annotations

import numpy as np
import trimesh

from fracture_gs.data.synthetic.meshing import Grid, solid_sdf_from_surface_samples

# 32 patches x 16 control-point indices (1-based, row-major 4x4: u major, v minor).
_PATCH_TABLE = """1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16
4 17 18 19 8 20 21 22 12 23 24 25 16 26 27 28
19 29 30 31 22 32 33 34 25 35 36 37 28 38 39 40
31 41 42 1 34 43 44 5 37 45 46 9 40 47 48 13
13 14 15 16 49 50 51 52 53 54 55 56 57 58 59 60
16 26 27 28 52 61 62 63 56 64 65 66 60 67 68 69
28 38 39 40 63 70 71 72 66 73 74 75 69 76 77 78
40 47 48 13 72 79 80 49 75 81 82 53 78 83 84 57
57 58 59 60 85 86 87 88 89 90 91 92 93 94 95 96
60 67 68 69 88 97 98 99 92 100 101 102 96 103 104 105
69 76 77 78 99 106 107 108 102 109 110 111 105 112 113 114
78 83 84 57 108 115 116 85 111 117 118 89 114 119 120 93
121 122 123 124 125 126 127 128 129 130 131 132 133 134 135 136
124 137 138 121 128 139 140 125 132 141 142 129 136 143 144 133
133 134 135 136 145 146 147 148 149 150 151 152 69 153 154 155
136 143 144 133 148 156 157 145 152 158 159 149 155 160 161 69
162 163 164 165 166 167 168 169 170 171 172 173 174 175 176 177
165 178 179 162 169 180 181 166 173 182 183 170 177 184 185 174
174 175 176 177 186 187 188 189 190 191 192 193 194 195 196 197
177 184 185 174 189 198 199 186 193 200 201 190 197 202 203 194
204 204 204 204 207 208 209 210 211 211 211 211 212 213 214 215
204 204 204 204 210 217 218 219 211 211 211 211 215 220 221 222
204 204 204 204 219 224 225 226 211 211 211 211 222 227 228 229
204 204 204 204 226 230 231 207 211 211 211 211 229 232 233 212
212 213 214 215 234 235 236 237 238 239 240 241 242 243 244 245
215 220 221 222 237 246 247 248 241 249 250 251 245 252 253 254
222 227 228 229 248 255 256 257 251 258 259 260 254 261 262 263
229 232 233 212 257 264 265 234 260 266 267 238 263 268 269 242
270 270 270 270 279 280 281 282 275 276 277 278 271 272 273 274
270 270 270 270 282 289 290 291 278 286 287 288 274 283 284 285
270 270 270 270 291 298 299 300 288 295 296 297 285 292 293 294
270 270 270 270 300 305 306 279 297 303 304 275 294 301 302 271
"""

# 306 control points (x y z), "|"-separated.
_VERTEX_TABLE = """
1.4 0 2.4|1.4 -0.784 2.4|0.784 -1.4 2.4|0 -1.4 2.4|1.3375 0 2.53125|1.3375 -0.749 2.53125
0.749 -1.3375 2.53125|0 -1.3375 2.53125|1.4375 0 2.53125|1.4375 -0.805 2.53125
0.805 -1.4375 2.53125|0 -1.4375 2.53125|1.5 0 2.4|1.5 -0.84 2.4|0.84 -1.5 2.4|0 -1.5 2.4
-0.784 -1.4 2.4|-1.4 -0.784 2.4|-1.4 0 2.4|-0.749 -1.3375 2.53125|-1.3375 -0.749 2.53125
-1.3375 0 2.53125|-0.805 -1.4375 2.53125|-1.4375 -0.805 2.53125|-1.4375 0 2.53125|-0.84 -1.5 2.4
-1.5 -0.84 2.4|-1.5 0 2.4|-1.4 0.784 2.4|-0.784 1.4 2.4|0 1.4 2.4|-1.3375 0.749 2.53125
-0.749 1.3375 2.53125|0 1.3375 2.53125|-1.4375 0.805 2.53125|-0.805 1.4375 2.53125
0 1.4375 2.53125|-1.5 0.84 2.4|-0.84 1.5 2.4|0 1.5 2.4|0.784 1.4 2.4|1.4 0.784 2.4
0.749 1.3375 2.53125|1.3375 0.749 2.53125|0.805 1.4375 2.53125|1.4375 0.805 2.53125|0.84 1.5 2.4
1.5 0.84 2.4|1.75 0 1.875|1.75 -0.98 1.875|0.98 -1.75 1.875|0 -1.75 1.875|2 0 1.35|2 -1.12 1.35
1.12 -2 1.35|0 -2 1.35|2 0 0.9|2 -1.12 0.9|1.12 -2 0.9|0 -2 0.9|-0.98 -1.75 1.875
-1.75 -0.98 1.875|-1.75 0 1.875|-1.12 -2 1.35|-2 -1.12 1.35|-2 0 1.35|-1.12 -2 0.9|-2 -1.12 0.9
-2 0 0.9|-1.75 0.98 1.875|-0.98 1.75 1.875|0 1.75 1.875|-2 1.12 1.35|-1.12 2 1.35|0 2 1.35
-2 1.12 0.9|-1.12 2 0.9|0 2 0.9|0.98 1.75 1.875|1.75 0.98 1.875|1.12 2 1.35|2 1.12 1.35|1.12 2 0.9
2 1.12 0.9|2 0 0.45|2 -1.12 0.45|1.12 -2 0.45|0 -2 0.45|1.5 0 0.225|1.5 -0.84 0.225
0.84 -1.5 0.225|0 -1.5 0.225|1.5 0 0.15|1.5 -0.84 0.15|0.84 -1.5 0.15|0 -1.5 0.15|-1.12 -2 0.45
-2 -1.12 0.45|-2 0 0.45|-0.84 -1.5 0.225|-1.5 -0.84 0.225|-1.5 0 0.225|-0.84 -1.5 0.15
-1.5 -0.84 0.15|-1.5 0 0.15|-2 1.12 0.45|-1.12 2 0.45|0 2 0.45|-1.5 0.84 0.225|-0.84 1.5 0.225
0 1.5 0.225|-1.5 0.84 0.15|-0.84 1.5 0.15|0 1.5 0.15|1.12 2 0.45|2 1.12 0.45|0.84 1.5 0.225
1.5 0.84 0.225|0.84 1.5 0.15|1.5 0.84 0.15|-1.6 0 2.025|-1.6 -0.3 2.025|-1.5 -0.3 2.25|-1.5 0 2.25
-2.3 0 2.025|-2.3 -0.3 2.025|-2.5 -0.3 2.25|-2.5 0 2.25|-2.7 0 2.025|-2.7 -0.3 2.025|-3 -0.3 2.25
-3 0 2.25|-2.7 0 1.8|-2.7 -0.3 1.8|-3 -0.3 1.8|-3 0 1.8|-1.5 0.3 2.25|-1.6 0.3 2.025|-2.5 0.3 2.25
-2.3 0.3 2.025|-3 0.3 2.25|-2.7 0.3 2.025|-3 0.3 1.8|-2.7 0.3 1.8|-2.7 0 1.575|-2.7 -0.3 1.575
-3 -0.3 1.35|-3 0 1.35|-2.5 0 1.125|-2.5 -0.3 1.125|-2.65 -0.3 0.9375|-2.65 0 0.9375|-2 -0.3 0.9
-1.9 -0.3 0.6|-1.9 0 0.6|-3 0.3 1.35|-2.7 0.3 1.575|-2.65 0.3 0.9375|-2.5 0.3 1.125|-1.9 0.3 0.6
-2 0.3 0.9|1.7 0 1.425|1.7 -0.66 1.425|1.7 -0.66 0.6|1.7 0 0.6|2.6 0 1.425|2.6 -0.66 1.425
3.1 -0.66 0.825|3.1 0 0.825|2.3 0 2.1|2.3 -0.25 2.1|2.4 -0.25 2.025|2.4 0 2.025|2.7 0 2.4
2.7 -0.25 2.4|3.3 -0.25 2.4|3.3 0 2.4|1.7 0.66 0.6|1.7 0.66 1.425|3.1 0.66 0.825|2.6 0.66 1.425
2.4 0.25 2.025|2.3 0.25 2.1|3.3 0.25 2.4|2.7 0.25 2.4|2.8 0 2.475|2.8 -0.25 2.475
3.525 -0.25 2.49375|3.525 0 2.49375|2.9 0 2.475|2.9 -0.15 2.475|3.45 -0.15 2.5125|3.45 0 2.5125
2.8 0 2.4|2.8 -0.15 2.4|3.2 -0.15 2.4|3.2 0 2.4|3.525 0.25 2.49375|2.8 0.25 2.475|3.45 0.15 2.5125
2.9 0.15 2.475|3.2 0.15 2.4|2.8 0.15 2.4|0 0 3.15|0 -0.002 3.15|0.002 0 3.15|0.8 0 3.15
0.8 -0.45 3.15|0.45 -0.8 3.15|0 -0.8 3.15|0 0 2.85|0.2 0 2.7|0.2 -0.112 2.7|0.112 -0.2 2.7
0 -0.2 2.7|-0.002 0 3.15|-0.45 -0.8 3.15|-0.8 -0.45 3.15|-0.8 0 3.15|-0.112 -0.2 2.7
-0.2 -0.112 2.7|-0.2 0 2.7|0 0.002 3.15|-0.8 0.45 3.15|-0.45 0.8 3.15|0 0.8 3.15|-0.2 0.112 2.7
-0.112 0.2 2.7|0 0.2 2.7|0.45 0.8 3.15|0.8 0.45 3.15|0.112 0.2 2.7|0.2 0.112 2.7|0.4 0 2.55
0.4 -0.224 2.55|0.224 -0.4 2.55|0 -0.4 2.55|1.3 0 2.55|1.3 -0.728 2.55|0.728 -1.3 2.55|0 -1.3 2.55
1.3 0 2.4|1.3 -0.728 2.4|0.728 -1.3 2.4|0 -1.3 2.4|-0.224 -0.4 2.55|-0.4 -0.224 2.55|-0.4 0 2.55
-0.728 -1.3 2.55|-1.3 -0.728 2.55|-1.3 0 2.55|-0.728 -1.3 2.4|-1.3 -0.728 2.4|-1.3 0 2.4
-0.4 0.224 2.55|-0.224 0.4 2.55|0 0.4 2.55|-1.3 0.728 2.55|-0.728 1.3 2.55|0 1.3 2.55
-1.3 0.728 2.4|-0.728 1.3 2.4|0 1.3 2.4|0.224 0.4 2.55|0.4 0.224 2.55|0.728 1.3 2.55
1.3 0.728 2.55|0.728 1.3 2.4|1.3 0.728 2.4|0 0 0|1.5 0 0.15|1.5 0.84 0.15|0.84 1.5 0.15|0 1.5 0.15
1.5 0 0.075|1.5 0.84 0.075|0.84 1.5 0.075|0 1.5 0.075|1.425 0 0|1.425 0.798 0|0.798 1.425 0
0 1.425 0|-0.84 1.5 0.15|-1.5 0.84 0.15|-1.5 0 0.15|-0.84 1.5 0.075|-1.5 0.84 0.075|-1.5 0 0.075
-0.798 1.425 0|-1.425 0.798 0|-1.425 0 0|-1.5 -0.84 0.15|-0.84 -1.5 0.15|0 -1.5 0.15
-1.5 -0.84 0.075|-0.84 -1.5 0.075|0 -1.5 0.075|-1.425 -0.798 0|-0.798 -1.425 0|0 -1.425 0
0.84 -1.5 0.15|1.5 -0.84 0.15|0.84 -1.5 0.075|1.5 -0.84 0.075|0.798 -1.425 0|1.425 -0.798 0
"""

TEAPOT_PATCHES = np.array([[int(i) - 1 for i in line.split()]
                           for line in _PATCH_TABLE.strip().splitlines()], dtype=np.int64)
TEAPOT_CONTROL_POINTS = np.array([[float(c) for c in entry.split()]
                                  for entry in _VERTEX_TABLE.replace("\n", "|").split("|")
                                  if entry.strip()], dtype=np.float64)

# Patch groups (0-based patch numbers) of the 32-patch set.
RIM, BODY, HANDLE, SPOUT, LID, BOTTOM = (range(0, 4), range(4, 12), range(12, 16),
                                        range(16, 20), range(20, 28), range(28, 32))


def patch_controls(patch: int) -> np.ndarray:
    """The (4, 4, 3) control net of one patch (first index u, second v)."""
    return TEAPOT_CONTROL_POINTS[TEAPOT_PATCHES[patch]].reshape(4, 4, 3)


def _bernstein(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Bernstein basis (len(t), 4) and its derivative."""
    s = 1.0 - t
    basis = np.stack([s ** 3, 3 * s ** 2 * t, 3 * s * t ** 2, t ** 3], axis=-1)
    derivative = np.stack([-3 * s ** 2, 3 * s ** 2 - 6 * s * t, 6 * s * t - 3 * t ** 2,
                           3 * t ** 2], axis=-1)
    return basis, derivative


def evaluate_patch(controls: np.ndarray, u: np.ndarray,
                   v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, du and dv tangents (len(u), len(v), 3) of a bicubic patch on the grid u x v."""
    bu, dbu = _bernstein(np.asarray(u, dtype=np.float64))
    bv, dbv = _bernstein(np.asarray(v, dtype=np.float64))
    points = np.einsum("ai,bj,ijc->abc", bu, bv, controls)
    tangent_u = np.einsum("ai,bj,ijc->abc", dbu, bv, controls)
    tangent_v = np.einsum("ai,bj,ijc->abc", bu, dbv, controls)
    return points, tangent_u, tangent_v


def _grid_triangles(rows: int, cols: int, offset: int) -> np.ndarray:
    """Two triangles per cell of a rows x cols vertex grid (row-major), indices + offset."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel() + offset
    b, d = a + 1, a + cols
    return np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, d + 1], 1)])


def tessellate_patches(segments: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Triangle soup (vertices, faces) of all 32 patches, ``segments`` x ``segments`` cells each.

    Neighbouring patches share their boundary curves, but vertices are not merged and the
    surface has the open places listed in the module docstring.
    """
    t = np.linspace(0.0, 1.0, segments + 1)
    vertices, faces = [], []
    for patch in range(len(TEAPOT_PATCHES)):
        points, _, _ = evaluate_patch(patch_controls(patch), t, t)
        faces.append(_grid_triangles(segments + 1, segments + 1, sum(len(v) for v in vertices)))
        vertices.append(points.reshape(-1, 3))
    return np.concatenate(vertices), np.concatenate(faces)


def _patch_edge(patch: int, which: str, count: int) -> np.ndarray:
    """Points along one boundary curve of a patch: ``which`` in u0, u1 (v varies) or v0, v1."""
    t = np.linspace(0.0, 1.0, count)
    controls = patch_controls(patch)
    if which in ("u0", "u1"):
        curve = controls[0 if which == "u0" else 3]
    else:
        curve = controls[:, 0 if which == "v0" else 3]
    basis, _ = _bernstein(t)
    return basis @ curve


def _loop(edges: list[tuple[int, str]], count: int) -> np.ndarray:
    """A closed curve made of patch boundary curves, each reoriented to continue the last."""
    loop: list[np.ndarray] = []
    for patch, which in edges:
        curve = _patch_edge(patch, which, count)
        if loop and np.linalg.norm(curve[-1] - loop[-1][-1]) < np.linalg.norm(
                curve[0] - loop[-1][-1]):
            curve = curve[::-1]
        loop.append(curve if not loop else curve[1:])
    return np.concatenate(loop)


def _fan(loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle fan (vertices, faces) closing a roughly planar, star-shaped loop."""
    center = loop.mean(axis=0)
    n = len(loop)
    faces = np.stack([np.zeros(n, dtype=np.int64), 1 + np.arange(n),
                      1 + (np.arange(n) + 1) % n], axis=1)
    return np.concatenate([center[None], loop]), faces


def _strip(inner: np.ndarray, outer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles joining two closed loops with the same number of points (point i to i)."""
    n = len(inner)
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.concatenate([np.stack([i, n + i, j], 1), np.stack([j, n + i, n + j], 1)])
    return np.concatenate([inner, outer]), faces


def closing_caps(count: int = 24) -> list[tuple[np.ndarray, np.ndarray]]:
    """Flat pieces that close the patch set: lid-rim annulus, spout plug, tube-end caps."""
    lid_edge = _loop([(p, "u1") for p in LID[4:]], count)       # radius 1.3 at z = 2.4
    rim_edge = _loop([(p, "u0") for p in RIM], count)           # radius 1.4 at z = 2.4
    caps = [_strip(lid_edge, rim_edge)]
    caps.append(_fan(_loop([(SPOUT[2], "u1"), (SPOUT[3], "u1")], count)))   # spout opening
    caps.append(_fan(_loop([(SPOUT[0], "u0"), (SPOUT[1], "u0")], count)))   # spout base
    caps.append(_fan(_loop([(HANDLE[0], "u0"), (HANDLE[1], "u0")], count)))  # handle top
    caps.append(_fan(_loop([(HANDLE[2], "u1"), (HANDLE[3], "u1")], count)))  # handle bottom
    return caps


def surface_samples(spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Dense points (N,3) and unoriented normals (N,3) on the closed teapot surface, about
    ``spacing`` apart (patches sampled on parameter grids, caps by random triangle samples)."""
    rng = np.random.default_rng(0)
    points, normals = [], []
    for patch in range(len(TEAPOT_PATCHES)):
        controls = patch_controls(patch)
        length_u = np.max(np.linalg.norm(np.diff(controls, axis=0), axis=-1).sum(axis=0))
        length_v = np.max(np.linalg.norm(np.diff(controls, axis=1), axis=-1).sum(axis=1))
        u = np.linspace(0.0, 1.0, max(4, int(np.ceil(length_u / spacing)) + 1))
        v = np.linspace(0.0, 1.0, max(4, int(np.ceil(length_v / spacing)) + 1))
        patch_points, tangent_u, tangent_v = evaluate_patch(controls, u, v)
        patch_normals = np.cross(tangent_u, tangent_v).reshape(-1, 3)
        valid = np.linalg.norm(patch_normals, axis=1) > 1e-9  # drop degenerate poles
        points.append(patch_points.reshape(-1, 3)[valid])
        normals.append(patch_normals[valid])
    for vertices, faces in closing_caps():
        cap = trimesh.Trimesh(vertices, faces, process=False)
        count = int(np.ceil(cap.area / spacing ** 2 * 2.0)) + 1
        cap_points, face_index = trimesh.sample.sample_surface(cap, count, seed=rng)
        points.append(np.asarray(cap_points))
        normals.append(cap.face_normals[face_index])
    return np.concatenate(points), np.concatenate(normals)


def teapot_sdf(resolution: int) -> tuple[np.ndarray, Grid]:
    """Signed distance grid of the solid teapot (Newell units) with ``resolution`` cells along
    its longest side."""
    lower = TEAPOT_CONTROL_POINTS.min(axis=0)
    upper = TEAPOT_CONTROL_POINTS.max(axis=0)
    grid = Grid.around(lower, upper, resolution, padding=5)
    points, normals = surface_samples(grid.spacing / 3.0)
    return solid_sdf_from_surface_samples(points, normals, grid), grid
