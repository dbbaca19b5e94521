"""Procedural solid textures: per-vertex base colours of every part, in natural object units.

Colours are written in sRGB (as a designer picks them) and returned as linear RGB reflectance
in [0, 1] for the renderer. All patterns are functions of position (solid textures), so they
continue across the surface without UV maps, and photometric fitting has detail to match.
"""
from __future__ import annotations

import numpy as np


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    srgb = np.asarray(srgb, dtype=np.float64)
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    linear = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def value_noise(points: np.ndarray, frequency: float, seed: int = 0) -> np.ndarray:
    """Smooth lattice value noise in [0, 1] at (N,3) points (trilinear, smoothstep-blended)."""
    rng = np.random.default_rng(seed)
    permutation = rng.permutation(256)
    lattice_values = rng.random(256)
    scaled = points * frequency
    base = np.floor(scaled).astype(np.int64)
    fraction = scaled - base
    weight = fraction * fraction * (3.0 - 2.0 * fraction)
    result = np.zeros(len(points))
    for corner in range(8):
        offset = np.array([(corner >> 0) & 1, (corner >> 1) & 1, (corner >> 2) & 1])
        cell = (base + offset) & 255
        hashed = permutation[(permutation[(permutation[cell[:, 0]] + cell[:, 1]) & 255]
                              + cell[:, 2]) & 255]
        corner_weight = np.prod(np.where(offset == 1, weight, 1.0 - weight), axis=1)
        result += corner_weight * lattice_values[hashed]
    return result


def fbm(points: np.ndarray, frequency: float, octaves: int = 4, seed: int = 0) -> np.ndarray:
    """Fractal sum of value noise, normalised to [0, 1]."""
    total, amplitude, norm = np.zeros(len(points)), 1.0, 0.0
    for octave in range(octaves):
        total += amplitude * value_noise(points, frequency * 2.0 ** octave, seed + octave)
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)[:, None]
    return (1.0 - t) * np.asarray(a, dtype=np.float64) + t * np.asarray(b, dtype=np.float64)


def _smooth_band(x: np.ndarray, center: float | np.ndarray, half_width: float,
                 softness: float = 0.01) -> np.ndarray:
    """1 inside |x - center| < half_width, 0 outside, with a soft edge."""
    return np.clip((half_width - np.abs(x - center)) / softness + 0.5, 0.0, 1.0)


def porcelain(points: np.ndarray) -> np.ndarray:
    """Teapot (Newell units): ivory glaze with a cobalt wave band, rim lines and knob."""
    ivory = np.array([0.93, 0.90, 0.82])
    cobalt = np.array([0.10, 0.20, 0.58])
    x, y, z = points.T
    angle = np.arctan2(y, x)
    colour = _mix(ivory, ivory * 0.9, fbm(points, 1.5, 3, seed=11))
    on_body = np.abs(x) < 1.95
    wave = _smooth_band(z, 1.30 + 0.13 * np.sin(8 * angle), 0.045, 0.02)
    dots = _smooth_band(z, 0.95, 0.09, 0.02) * (np.cos(16 * angle) > 0.55)
    lines = _smooth_band(z, 1.72, 0.025, 0.01) + _smooth_band(z, 0.62, 0.025, 0.01)
    rim = _smooth_band(z, 2.30, 0.03, 0.01)
    knob = (z > 2.78).astype(np.float64)
    blue = np.clip(on_body * (wave + dots + lines) + rim + knob, 0.0, 1.0)
    return srgb_to_linear(_mix(colour, cobalt, blue))


def glazed_bowl(points: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Bowl: speckled teal outside, cream inside with a terracotta ring, bare clay foot."""
    r = np.hypot(points[:, 0], points[:, 1])
    z = points[:, 2]
    speckle = (value_noise(points, 40.0, seed=3) > 0.82).astype(np.float64)
    outside = _mix([0.07, 0.36, 0.42], [0.02, 0.18, 0.22], fbm(points, 3.0, 3, seed=4))
    outside = _mix(outside, [0.85, 0.85, 0.78], 0.6 * speckle)
    inside = _mix([0.95, 0.90, 0.78], [0.88, 0.80, 0.66], fbm(points, 4.0, 3, seed=5))
    ring = _smooth_band(r, 0.22, 0.035, 0.01) + _smooth_band(r, 0.80, 0.02, 0.01)
    inside = _mix(inside, [0.72, 0.30, 0.16], ring)
    colour = np.where(inner[:, None], inside, outside)
    foot = (z < 0.125) & (r > 0.33) & (r < 0.47) & ~inner
    colour = np.where(foot[:, None], _mix([0.74, 0.58, 0.43], [0.62, 0.47, 0.34],
                                          fbm(points, 12.0, 2, seed=6)), colour)
    return srgb_to_linear(colour)


def oak_top(points: np.ndarray) -> np.ndarray:
    """Table top: light oak, growth rings around an axis along x, warped by noise."""
    warp = fbm(points * np.array([0.3, 1.0, 1.0]), 3.0, 3, seed=7) - 0.5
    warped = points + 0.05 * warp[:, None]
    distance = np.hypot(warped[:, 1] + 0.9, warped[:, 2] - 0.2)
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * 14.0 * distance)
    fine = fbm(points * np.array([0.2, 6.0, 6.0]), 8.0, 2, seed=8)
    colour = _mix([0.80, 0.60, 0.38], [0.58, 0.38, 0.20], 0.75 * rings ** 3 + 0.25 * fine)
    return srgb_to_linear(colour)


def walnut_legs(points: np.ndarray) -> np.ndarray:
    """Table legs: dark walnut with grain along z."""
    grain = fbm(points * np.array([8.0, 8.0, 0.4]), 6.0, 3, seed=9)
    return srgb_to_linear(_mix([0.46, 0.27, 0.15], [0.16, 0.08, 0.04], 1.6 * grain - 0.3))


def terracotta_pot(points: np.ndarray, soil_level: float, inner_radius: float) -> np.ndarray:
    """Pot: terracotta with a darker lip band; the soil surface inside is dark brown."""
    r = np.hypot(points[:, 0], points[:, 1])
    clay = _mix([0.78, 0.40, 0.22], [0.62, 0.28, 0.15], fbm(points, 10.0, 3, seed=10))
    clay = _mix(clay, [0.55, 0.24, 0.12], _smooth_band(points[:, 2], 0.50, 0.035, 0.01))
    soil = _mix([0.24, 0.16, 0.10], [0.12, 0.08, 0.05], fbm(points, 30.0, 3, seed=12))
    is_soil = (np.abs(points[:, 2] - soil_level) < 0.006) & (r < inner_radius - 0.002)
    return srgb_to_linear(np.where(is_soil[:, None], soil, clay))


def bark(points: np.ndarray) -> np.ndarray:
    """Trunk and branches: grey-brown bark with fine streaks."""
    streaks = fbm(points * np.array([6.0, 6.0, 1.0]), 20.0, 3, seed=13)
    return srgb_to_linear(_mix([0.50, 0.40, 0.30], [0.30, 0.22, 0.15], streaks))


def foliage(points: np.ndarray) -> np.ndarray:
    """Leaves: greens varying from leaf to leaf (low-frequency noise) and within a leaf."""
    per_leaf = value_noise(points, 12.0, seed=14)
    detail = fbm(points, 60.0, 2, seed=15)
    colour = _mix([0.16, 0.42, 0.10], [0.40, 0.62, 0.18], per_leaf)
    return srgb_to_linear(_mix(colour, colour * 0.7, detail))
