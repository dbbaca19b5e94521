"""Fragments of a simulation state: connected pieces of each object's particles.

Two particles of one object are linked when they are closer than ``LINK_SPACINGS`` times that
object's rest particle spacing (the cube root of the median rest volume of its particles: objects
sampled at different densities, such as a trained teapot and a trained table, each hold together
at rest) and neither is a brittle particle with complete damage (crushed material or a crack face
links to nothing); a fragment is a connected component of these links inside one object,
computed in C++ on a hash grid (:func:`fracture_gs.fracture.spatial.connected_components`).
Labels are numbered by the smallest particle index of each piece, so they do not depend on the
solver's internal particle order when the positions are given in input order.
"""
from __future__ import annotations

import torch

from fracture_gs.fracture.spatial import connected_components

LINK_SPACINGS = 1.5            # link distance, in rest particle spacings (docs/formulas.md §8)
MIN_FRAGMENT_FRACTION = 0.01   # diagnostics count pieces with at least this share of their object


def link_radius(rest_volume: torch.Tensor) -> float:
    """Link distance of the fragment graph: 1.5 x the rest particle spacing (median volume)."""
    if rest_volume.numel() == 0:
        return 1.0
    return LINK_SPACINGS * float(rest_volume.float().median()) ** (1.0 / 3.0)


def object_link_radii(rest_volume: torch.Tensor, obj_id: torch.Tensor, n_objects: int) -> torch.Tensor:
    """(n_objects,) float32 link distance of each object: :func:`link_radius` of its own particles
    (1.0 for an object without particles)."""
    radii = [link_radius(rest_volume[obj_id == k]) for k in range(n_objects)]
    return torch.tensor(radii, dtype=torch.float32, device=rest_volume.device)


def fragment_ids(x: torch.Tensor, obj_id: torch.Tensor, radius: float | torch.Tensor, backend: str = "auto",
                 broken: torch.Tensor | None = None) -> torch.Tensor:
    """(N,) int64 fragment label of every particle (pieces never span two objects), numbered in the
    order of each piece's smallest particle index. ``radius``: one link distance, or one per object
    ((n_objects,) tensor, :func:`object_link_radii`). ``broken`` (N,) bool: particles that link to
    nothing (a brittle particle with complete damage is crushed material or a crack face: a crack
    through an object parts its pieces even while they still touch); each is a piece of its own."""
    if x.shape[0] == 0:
        return torch.zeros(0, dtype=torch.int64, device=x.device)
    if isinstance(radius, torch.Tensor):
        # Links never cross objects, so each object's radius becomes 1 in its own scaled copy.
        x = x / radius.to(x.device, x.dtype)[obj_id.long()][:, None]
        radius = 1.0
    if broken is None or not bool(broken.any()):
        return connected_components(x, radius, group=obj_id, backend=backend)
    whole = torch.nonzero(~broken).flatten()
    roots = torch.arange(x.shape[0], device=x.device, dtype=torch.int64)
    if len(whole):
        labels = connected_components(x[whole].contiguous(), radius, group=obj_id[whole].contiguous(),
                                      backend=backend)
        first = torch.full((len(whole),), x.shape[0], dtype=torch.int64, device=x.device)
        first = first.scatter_reduce(0, labels, whole, "amin")  # smallest particle of each piece
        roots[whole] = first[labels]
    return torch.unique(roots, return_inverse=True)[1]


def _counted_fragments(labels: torch.Tensor, obj_id: torch.Tensor,
                       min_fraction: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(sizes, counted, owner) per label: the fragment's particle count, whether it is a fragment
    holding at least ``min_fraction`` of its object's particles, and its object."""
    labels = labels.long()
    sizes = torch.bincount(labels)
    owner = torch.zeros_like(sizes).scatter_(0, labels, obj_id.long())  # object of each fragment
    object_sizes = torch.bincount(obj_id.long())
    return sizes, (sizes > 0) & (sizes >= min_fraction * object_sizes[owner]), owner


def count_fragments(labels: torch.Tensor, obj_id: torch.Tensor,
                    min_fraction: float = MIN_FRAGMENT_FRACTION) -> int:
    """Number of fragments holding at least ``min_fraction`` of their object's particles."""
    if labels.numel() == 0:
        return 0
    return int(_counted_fragments(labels, obj_id, min_fraction)[1].sum())


def fragments_per_object(labels: torch.Tensor, obj_id: torch.Tensor, n_objects: int,
                         min_fraction: float = MIN_FRAGMENT_FRACTION) -> tuple[torch.Tensor, torch.Tensor]:
    """(counted, largest), each (n_objects,) int64: per object, the fragments that
    :func:`count_fragments` counts and the particle count of its largest fragment (0 for an object
    without particles)."""
    counted = torch.zeros(n_objects, dtype=torch.int64, device=labels.device)
    largest = torch.zeros(n_objects, dtype=torch.int64, device=labels.device)
    if labels.numel() == 0:
        return counted, largest
    sizes, is_counted, owner = _counted_fragments(labels, obj_id, min_fraction)
    counted.index_add_(0, owner, is_counted.long())
    largest.scatter_reduce_(0, owner, sizes, "amax")
    return counted, largest


def piece_ranks(labels: torch.Tensor, obj_id: torch.Tensor,
                min_fraction: float = MIN_FRAGMENT_FRACTION) -> torch.Tensor:
    """(N,) int64 rank of every particle's fragment among the fragments that :func:`count_fragments`
    counts (at least ``min_fraction`` of their object's particles): 0 for the largest of them, 1
    for the next (ties: smaller label first), ...; -1 for the particles of smaller fragments. What
    the pictures colour by (``tools/figures/fragment_strip.py``, ``view.py``'s "colour by piece")."""
    if labels.numel() == 0:
        return torch.zeros(0, dtype=torch.int64, device=labels.device)
    sizes, counted, _ = _counted_fragments(labels, obj_id, min_fraction)
    candidates = torch.nonzero(counted).flatten()                     # ascending labels
    order = torch.argsort(sizes[candidates], descending=True, stable=True)
    rank_of_label = torch.full_like(sizes, -1)
    rank_of_label[candidates[order]] = torch.arange(len(candidates), device=labels.device)
    return rank_of_label[labels.long()]


def fragment_sizes(labels: torch.Tensor) -> list[int]:
    """Particle counts of the fragments, largest first."""
    return sorted(torch.bincount(labels).tolist(), reverse=True) if labels.numel() else []
