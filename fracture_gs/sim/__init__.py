"""Reading simulation output folders (``simulate.py``'s ``output/sims/<name>/``)."""
from fracture_gs.sim.folder import SimFrame, SimParticles, Simulation, SimulationError

__all__ = ["SimFrame", "SimParticles", "Simulation", "SimulationError"]
