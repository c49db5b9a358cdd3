"""The static model of an XPBD cloth run (NVIDIA Newton's Model): what a ClothSolver is built from and what never
changes while it steps. Where the pins, the body and the harmonic target are comes per frame (FrameInputs)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.xpbd.constraints import HarmonicConstraint
from sim.xpbd.settings import SolverSettings

MAX_CAPSULES = 255     # a vertex lists the capsules it watches as bytes of one int32 (body_contact.WATCHED)


@dataclass(frozen=True, eq=False)
class ClothModel:
    """A cloth mesh and what holds it, shared by every world a solver steps: the rest mesh, the settings
    (integration, material, physics switches), the pinned vertices (they follow FrameInputs.pin_targets), the
    harmonic constraint of a high-res run (its target comes per frame) and, with body collision, the body's shape:
    each capsule's radii at its two ends (its end points come per frame). Checked when made: a ValueError names
    the first field that does not fit. The mesh's arrays keep their dtype (the solver computes masses and rest
    lengths from them as given); pinned becomes int64, the radii float64."""

    rest_vertices: np.ndarray                      # (V, 3)
    faces: np.ndarray                              # (T, 3) integer vertex ids
    settings: SolverSettings
    pinned: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))   # (P,) vertex ids
    harmonic: HarmonicConstraint | None = None     # a high-res run's hard constraint B^T M (x - S x_low) = 0
    capsule_radii: np.ndarray | None = None        # (N, 2) radii at each capsule's ends, with body collision only

    def __post_init__(self):
        rest, faces = np.asarray(self.rest_vertices), np.asarray(self.faces)
        if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 3 or rest.dtype.kind not in "fiu" \
                or not np.isfinite(rest).all():
            raise ValueError(f"rest_vertices must be (V, 3) finite numbers, V >= 3; got {rest.dtype}{rest.shape}")
        n = len(rest)
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.dtype.kind not in "iu" \
                or faces.min() < 0 or faces.max() >= n:
            raise ValueError(f"faces must be (T, 3) ids of the {n} rest vertices; got {faces.dtype}{faces.shape}")
        pinned = np.asarray(self.pinned)
        if pinned.ndim != 1 or (pinned.size and (pinned.dtype.kind not in "iu" or pinned.min() < 0
                                                 or pinned.max() >= n)):
            raise ValueError(f"pinned must be (P,) ids of the {n} rest vertices; got {pinned.dtype}{pinned.shape}")
        object.__setattr__(self, "rest_vertices", rest)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "pinned", pinned.astype(np.int64))
        if self.harmonic is not None:
            mass, correction = self.harmonic.mass_basis.shape, self.harmonic.correction_basis.shape
            if mass != correction or len(mass) != 2 or mass[0] != n or mass[1] < 1:
                raise ValueError(f"the harmonic constraint's bases must both be (V, K) with V = {n} and K >= 1; got "
                                 f"{mass} and {correction}")
        object.__setattr__(self, "capsule_radii", self._checked_radii())

    def _checked_radii(self) -> np.ndarray | None:
        """The capsule radii as float64, present exactly when the settings collide with the body."""
        if not self.settings.body_collision:
            if self.capsule_radii is not None:
                raise ValueError("capsule radii were given but settings.body_collision is off")
            return None
        if self.capsule_radii is None:
            raise ValueError("body_collision needs capsules: their radii (N, 2) in the model, their ends at each "
                             "frame")
        radii = np.asarray(self.capsule_radii, dtype=np.float64)
        if radii.ndim != 2 or radii.shape[1] != 2 or not 1 <= len(radii) <= MAX_CAPSULES:
            raise ValueError(f"capsule_radii must be (N, 2) with 1 <= N <= {MAX_CAPSULES} capsules; got "
                             f"{radii.shape}")
        if not (np.isfinite(radii).all() and (radii > 0).all()):
            raise ValueError("capsule radii must be finite and positive")
        return radii
