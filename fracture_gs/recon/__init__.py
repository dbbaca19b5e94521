"""Reconstruction (train.py, docs/training.md): visual hull → photometric SDF refinement → mesh →
particles → isotropic Gaussians, and the model folder they are written to."""
