"""Reconstruction (train.py, SPEC §4): visual hull → photometric SDF refinement → mesh →
particles → isotropic Gaussians, and the model folder they are written to."""
