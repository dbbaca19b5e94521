"""Pieces of each object at a simulation's last frame: what "it shattered" means in numbers.

A piece is a fragment (``fragment_id`` of the frame, :mod:`fracture_gs.mpm.fragments`) holding
at least 1 % of its object's particles, the count ``diagnostics.csv``'s ``fragments`` column
gives for the whole scene. Beside it: the largest piece's share of its object and the share of
brittle particles with complete damage (crushed material and crack faces, which link to nothing).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

from fracture_gs.folders.sim_reader import Simulation, load_frame
from fracture_gs.mpm.fragments import fragments_per_object


@dataclass(frozen=True)
class ObjectPieces:
    """The pieces of one object at one frame."""

    name: str
    frame: int
    pieces: int                     # fragments of >= 1 % of the object's particles
    largest_share: float            # particles of the largest fragment / the object's particles
    complete_damage_share: float    # particles with damage 1 / the object's particles

    def to_json(self) -> dict:
        return asdict(self)


def object_pieces(fragment_id: np.ndarray, obj_id: np.ndarray, names: list[str], frame: int,
                  damage: np.ndarray | None = None) -> list[ObjectPieces]:
    """:class:`ObjectPieces` of every object from one frame's per-particle fragment labels."""
    labels, objects = torch.from_numpy(fragment_id).long(), torch.from_numpy(obj_id).long()
    counted, largest = fragments_per_object(labels, objects, len(names))
    particles = torch.bincount(objects, minlength=len(names)).clamp_min(1)  # 0 / 1 for an empty object
    crushed = (torch.bincount(objects, weights=torch.from_numpy(damage >= 1.0).double(), minlength=len(names))
               if damage is not None else torch.zeros(len(names), dtype=torch.float64))
    return [ObjectPieces(name, frame, int(counted[k]), float(largest[k]) / int(particles[k]),
                         float(crushed[k]) / int(particles[k])) for k, name in enumerate(names)]


def last_frame_pieces(sim: Simulation) -> list[ObjectPieces] | None:
    """Pieces of every object at the simulation's last frame; None when its frames carry no
    ``fragment_id`` (runs of older versions)."""
    frame = sim.frames[-1]
    arrays = load_frame(sim.frame_path(frame))
    if "fragment_id" not in arrays:
        return None
    return object_pieces(arrays["fragment_id"], sim.particles.obj_id, sim.object_names, frame,
                         arrays.get("damage"))
