"""The built model as plain NumPy arrays: what the builder produces, the cache
stores and :class:`taichi_lap.sim.model.Model` uploads to the device.

All organs are concatenated: particle, cluster, constraint, tet and surface
indices are global. Per-organ ranges are kept in :class:`OrganRecord` for
statistics and drawing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from taichi_lap.core.topology import OrganRecord

PARTICLE_MATERIAL = (
    "stiffness",
    "recover_rate",
    "eta_on_contact",
    "haptic_mass_ratio",
    "damping",
    "lra_relaxation",
)
"""Per-particle material channels copied from each organ's material table."""

FIXED_FIT_WEIGHT = 1000.0
"""How many times its mass a fixed particle weighs in the shape-matching fits."""


def fit_weights(mass: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """Each particle's weight [kg] in its clusters' fits (seed 000 Alg. 1 lines 8-10:
    the mass centre p_cm and A = Σ m (p - p_cm) q^T): its mass, and
    :data:`FIXED_FIT_WEIGHT` times that where it is fixed. A fixed particle has
    infinite mass (inverse mass 0), and the least-squares rigid fit of a cluster
    weighted by mass (Müller et al. 2005, "Meshless deformations based on shape
    matching": its optimal translation is the mass centre) then keeps a fixed member
    in place. With the mass itself a cluster that holds fixed particles follows the
    free ones instead, so a body fixed at its base sagged, goal after goal, until it
    folded through the base (an 8 mm tet cube at 4 substeps: its top 18 mm lower, 0.4
    mm with this weight). A thousand times is infinite enough for f32 sums and leaves
    the fits' arithmetic well conditioned."""
    return np.where(pinned, FIXED_FIT_WEIGHT, 1.0) * mass


@dataclass
class ModelData:
    """Static model: rest shape, masses, materials, clusters, constraints, surfaces.

    Shapes: ``N`` particles, ``C`` clusters, ``K`` cluster memberships, ``D``
    distance constraints, ``L`` long-range attachments, ``S`` springs, ``T`` tets,
    ``V`` surface vertices, ``F`` surface triangles. Units: metres, kilograms.
    """

    rest_position: np.ndarray  # (N, 3) [m]
    mass: np.ndarray  # (N,) [kg]; pinned particles keep their mass
    pinned: np.ndarray  # (N,) bool: fixed at the rest position
    radius: np.ndarray  # (N,) contact radius [m]
    organ: np.ndarray  # (N,) organ index
    material: dict[str, np.ndarray]  # PARTICLE_MATERIAL name -> (N,)
    cluster_start: np.ndarray  # (C + 1,)
    cluster_member: np.ndarray  # (K,)
    cluster_radius: np.ndarray  # (C,) [m]
    distance_pair: np.ndarray  # (D, 2) struts, sheet edges
    distance_rest: np.ndarray  # (D,) [m]
    distance_stiffness: np.ndarray  # (D,) PBD stiffness in [0, 1] (seed 000 Alg. 2)
    lra_particle: np.ndarray  # (L,) constrained particle
    lra_anchor: np.ndarray  # (L,) attached (pinned) particle
    lra_rest: np.ndarray  # (L,) d_LRA' [m] (seed 000 Eq. 3)
    spring_pair: np.ndarray  # (S, 2)
    spring_rest: np.ndarray  # (S,) [m]
    spring_stiffness: np.ndarray  # (S,) [N/m]
    spring_damping: np.ndarray  # (S,) [N s/m]
    tets: np.ndarray  # (T, 4)
    surface_index: np.ndarray  # (V, 4) particles each surface vertex follows
    surface_weight: np.ndarray  # (V, 4) barycentric / direct weights
    surface_triangles: np.ndarray  # (F, 3) into surface vertices
    organs: list[OrganRecord] = field(default_factory=list)

    @property
    def particle_count(self) -> int:
        return len(self.rest_position)

    @property
    def cluster_count(self) -> int:
        return len(self.cluster_start) - 1

    def inverse_mass(self) -> np.ndarray:
        """(N,) 1 / mass [1/kg], 0 for pinned particles (they do not move)."""
        return np.where(self.pinned, 0.0, 1.0 / np.maximum(self.mass, 1e-12))

    def fit_mass(self) -> np.ndarray:
        """(N,) each particle's weight in its clusters' fits [kg] (:func:`fit_weights`)."""
        return fit_weights(self.mass, self.pinned)

    def surface_particles(self) -> np.ndarray:
        """Sorted particles the surface vertices are bound to (weights > 0)."""
        return np.unique(self.surface_index[self.surface_weight > 0])

    def rest_surface(self) -> np.ndarray:
        """(V, 3) [m]: each surface vertex where its particles' rest positions put it."""
        return (self.surface_weight[..., None] * self.rest_position[self.surface_index]).sum(axis=1)

    def contact_radius(self) -> np.ndarray:
        """(N,) how far [m] a tool stays from each particle: the drawn surface's
        distance from it. Surfaces are drawn through their particles (0), and so is
        the membrane of a spring sheet; its row 0 is drawn as a tube of the row's
        radius around the masses."""
        radius = np.zeros(self.particle_count)
        for organ in self.organs:
            if organ.row_length:
                row0 = slice(organ.particles[0], organ.particles[0] + organ.row_length)
                radius[row0] = self.radius[row0]
        return radius

    def arrays(self) -> dict[str, np.ndarray]:
        """Flat name -> array mapping (for the cache)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                out[f.name] = value
        for name, value in self.material.items():
            out[f"material.{name}"] = value
        return out
