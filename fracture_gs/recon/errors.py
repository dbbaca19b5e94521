"""The error type of the reconstruction stages for problems with the user's input."""
from __future__ import annotations


class ReconstructionError(ValueError):
    """Bad input found while reconstructing (empty masks, empty mesh, a parts file that names
    no particle ...). The message is one line naming the file or flag and what to try."""
