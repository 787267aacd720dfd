"""Collision, orchestrated: tissue collision of surface triangles against each other
and the tools (seed 000 §4, :mod:`.tissue`, with its surface tables and pair lists)
and the stochastic self-collision of the intestine and mesentery (seed 001 §4,
:mod:`.intestine`). Their kernels are in :mod:`taichi_lap.kernels.collision`; the
tools' shapes are the Control's (:mod:`taichi_lap.core.instruments`)."""

from taichi_lap.collision.intestine import IntestineCollision
from taichi_lap.collision.tissue import METHODS, TissueCollision

__all__ = ["IntestineCollision", "METHODS", "TissueCollision"]
