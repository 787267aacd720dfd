"""Model / State / Control / Solver: the simulation objects (seed 000 §3, seed 001 §3, seed 002 §3)."""

from taichi_lap.sim.control import Control
from taichi_lap.sim.model import Model
from taichi_lap.sim.solver import Solver, SolverSettings
from taichi_lap.sim.state import State

__all__ = ["Control", "Model", "Solver", "SolverSettings", "State"]
