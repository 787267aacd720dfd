"""Collision kernels, one file per stage: closest points (Ericson 2004), the tools'
implicit shapes and the particle contacts, the spatial hash and broad phase (seed 000
§4.1), the circumspheres and bounding spheres with their phases (§4.1-4.2), the
polygon baseline (§4.4), the impulse response (§4.3), and the stochastic
self-collision of the intestine (seed 001 §4). The pipeline that orders them is
:mod:`taichi_lap.collision`."""
