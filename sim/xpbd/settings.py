"""The settings of an XPBD cloth run: integration, material, and the physics switches."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SolverSettings:
    """Everything that defines the integration; units are scene units (~m), seconds and kilograms."""
    dt: float = 1.0 / 60.0
    substeps: int = 8
    iterations: int = 75
    compression_allowance: float = 0.75  # stretch constraints allow compression down to this fraction of rest length
    stretch_compliance: float = 0.0      # XPBD compliance of stretch constraints (inverse stiffness, m/N)
    bending_compliance: float = 1.0e-3   # XPBD compliance of cross-edge bending links
    damping: float = 0.1                 # velocity decay rate (1/s): v <- v exp(-damping h) every substep
    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    density: float = 0.2                 # area density of the cloth (kg per square unit)
    relaxation: float = 1.5              # Jacobi over-relaxation, see kernels.distance_correction
    max_speed: float = 100.0             # a vertex faster than this (units/s) means the run has blown up
    bending: bool = True                 # physics switch: cross-edge bending links
    body_collision: bool = False         # physics switch: keep the cloth outside the body's capsules
    self_collision: bool = False         # physics switch: vertex-triangle self-contact
    collision_thickness: float = 0.005   # least distance of the cloth from every capsule surface
    friction: float = 0.3                # Coulomb coefficient against the (moving) body
    self_thickness: float = 0.004        # least distance of a vertex from a non-incident triangle
    harmonic_every: str = "iteration"    # project onto the harmonic constraint after every "iteration" or once a
                                         # "substep" (after its last iteration): 1/iterations of the cost
    contact_rounds: int = 3              # with the harmonic constraint and the body: rounds of clearing the body
                                         # and projecting that end a substep (friction first), which hold both;
                                         # 0: friction and clearance after the last projection only
    frame_end_rounds: int = 0            # more such rounds after a frame's last substep only, where the frame is
                                         # stored (the alternation converges linearly; a round is 4 launches)
    frame_kernel: str = "sweeps"         # "sweeps": a kernel per sweep. "auto": on a GPU with thread block
                                         # clusters (compute capability 9.0) cloths whose worlds fit a
                                         # cluster's shared memory (no harmonic constraint, at most
                                         # block_frame.SHARED_VERTICES vertices), few enough that each gets a
                                         # whole cluster of 16 blocks, step a frame in one launch (a cluster of
                                         # blocks per world, sim.xpbd.block_frame); else, and on the CPU, the
                                         # sweeps. "block": the one launch wherever the cloth fits
                                         # (block_frame.MAX_BLOCK_VERTICES), the CPU too. The sweeps stay the
                                         # default: on an H200 the clusters step one 757-vertex pants with body
                                         # and self-contact 1.6x faster at 8 x 75, 1.10x at 1 x 20, but the
                                         # simulate stage's batches are faster with the sweeps, and the key's
                                         # absence in settings written before it existed means sweeps
                                         # (docs/performance.md, "One launch a frame")

    def __post_init__(self):
        # NaN fails every range check below, but inf passes the open-ended ones (dt > 0, damping >= 0, ...)
        if self.harmonic_every not in ("iteration", "substep"):
            raise ValueError(f"solver setting 'harmonic_every' must be 'iteration' or 'substep', got "
                             f"{self.harmonic_every!r}")
        if self.frame_kernel not in ("auto", "block", "sweeps"):
            raise ValueError(f"solver setting 'frame_kernel' must be 'auto', 'block' or 'sweeps', got "
                             f"{self.frame_kernel!r}")
        not_finite = [name for name, value in vars(self).items()
                      if not isinstance(value, str) and not np.all(np.isfinite(value))]
        if not_finite:
            raise ValueError(f"solver setting '{not_finite[0]}' is not finite: {getattr(self, not_finite[0])}")
        checks = {
            "dt": self.dt > 0, "substeps": self.substeps >= 1, "iterations": self.iterations >= 1,
            "compression_allowance": 0 < self.compression_allowance <= 1,
            "stretch_compliance": self.stretch_compliance >= 0, "bending_compliance": self.bending_compliance >= 0,
            "damping": self.damping >= 0, "density": self.density > 0,
            "relaxation": 0 < self.relaxation < 2, "max_speed": self.max_speed > 0,
            "collision_thickness": self.collision_thickness > 0, "friction": self.friction >= 0,
            "self_thickness": self.self_thickness > 0, "contact_rounds": self.contact_rounds >= 0,
            "frame_end_rounds": self.frame_end_rounds >= 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"solver setting '{bad[0]}' out of range: {getattr(self, bad[0])}")
