"""On-disk formats and the rules that keep data safe: the one atomic write, device choice,
output folders made before work starts, folder locks, manifests of written files, the layouts of
the simulation and model folders, and particles.ply."""
