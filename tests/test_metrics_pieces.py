"""Pieces per object (fracture_gs.metrics.pieces): counts, largest share, complete damage."""
from __future__ import annotations

import numpy as np

from fracture_gs.metrics.pieces import object_pieces


def test_pieces_count_fragments_of_at_least_one_percent_of_their_object() -> None:
    # object 0: 300 particles in fragments of 240, 57 and 3 particles (1 % is 3: all three count)
    # object 1: 400 particles in fragments of 396 and 3 + 1 singles (1 % is 4: one counts)
    labels = np.concatenate([np.zeros(240), np.ones(57), np.full(3, 2),
                             np.full(396, 3), np.full(3, 4), [5]]).astype(np.int64)
    obj_id = np.concatenate([np.zeros(300), np.ones(400)]).astype(np.int32)
    damage = np.zeros(700, dtype=np.float32)
    damage[:30] = 1.0            # 10 % of object 0 completely damaged
    damage[300:304] = 0.99       # not complete
    first, second = object_pieces(labels, obj_id, ["cup", "floor"], 7, damage)
    assert (first.name, first.frame, first.pieces) == ("cup", 7, 3)
    assert np.isclose(first.largest_share, 0.8) and np.isclose(first.complete_damage_share, 0.1)
    assert (second.pieces, second.complete_damage_share) == (1, 0.0)
    assert np.isclose(second.largest_share, 0.99)


def test_an_object_without_particles_has_no_pieces() -> None:
    labels = np.zeros(5, dtype=np.int64)
    obj_id = np.zeros(5, dtype=np.int32)
    only, empty = object_pieces(labels, obj_id, ["a", "b"], 0)
    assert (only.pieces, only.largest_share) == (1, 1.0)
    assert (empty.pieces, empty.largest_share, empty.complete_damage_share) == (0, 0.0, 0.0)
