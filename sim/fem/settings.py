"""The settings of a quasi-static FEM run: the material and how each frame's energy minimisation is solved."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FemSettings:
    """Material in scene units (Pa if the scene is in metres), the Newton solve and its stopping rule.

    The residual is the largest unbalanced force on a free node divided by mu h^2 (h: the mean rest edge length),
    a number that does not depend on the scene's units, size or resolution: 1e-6 is a millionth of the force a
    unit strain puts on one element face."""
    youngs_modulus: float = 1.0e5        # E of soft tissue is 10-100 kPa; quasi-static, so only E/nu's ratio matters
    poisson_ratio: float = 0.45          # nearly incompressible flesh; 0.5 would lock
    residual_tolerance: float = 1.0e-6   # a frame has converged when its residual is at most this
    newton_iterations: int = 30          # at most this many Newton steps a load step
    load_steps: int = 1                  # a frame's bone motion applied in this many equal steps, each minimised
    cg_tolerance: float = 1.0e-3         # each Newton step's CG stops at this relative residual (inexact Newton)
    cg_iterations: int = 500             # and after this many iterations at most
    line_search_halvings: int = 20       # backtracking: the step is halved at most this many times

    def __post_init__(self):
        not_finite = [name for name, value in vars(self).items() if not np.isfinite(value)]
        if not_finite:
            raise ValueError(f"fem setting '{not_finite[0]}' is not finite: {getattr(self, not_finite[0])}")
        checks = {
            "youngs_modulus": self.youngs_modulus > 0, "poisson_ratio": 0 <= self.poisson_ratio < 0.5,
            "residual_tolerance": self.residual_tolerance > 0, "newton_iterations": self.newton_iterations >= 1,
            "load_steps": self.load_steps >= 1, "cg_tolerance": 0 < self.cg_tolerance < 1,
            "cg_iterations": self.cg_iterations >= 1, "line_search_halvings": self.line_search_halvings >= 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"fem setting '{bad[0]}' out of range: {getattr(self, bad[0])}")

    @property
    def lame(self) -> tuple[float, float]:
        """(mu, lambda) of the stable Neo-Hookean energy. Its small-strain limit is linear elasticity with Lame
        parameters mu and lambda - mu (Smith et al. 2018, sec. 3.4), so lambda is the linear one plus mu: E and nu
        mean what they mean for linear elasticity."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        mu = e / (2.0 * (1.0 + nu))
        return mu, e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)) + mu
