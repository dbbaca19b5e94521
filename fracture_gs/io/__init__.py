"""On-disk formats: one module per format (atomic writes, device choice, simulation and model
folders, particles.ply, manifests of written files, run locks)."""
