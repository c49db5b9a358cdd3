"""Shapes held clear of the mannequin's capsules outside the solver's step."""
from __future__ import annotations

import numpy as np
import warp as wp

from sim.xpbd import collision


def outside_body(points: np.ndarray, capsules: np.ndarray, radii: np.ndarray, thickness: float,
                 device: str) -> np.ndarray:
    """Points (F, N, 3) moved to `thickness` outside frame f's capsules (F, P, 2, 3) with radii (P, 2), by the
    projection the solver ends each substep with; points already that far out stay where they are."""
    points = np.asarray(points, dtype=np.float32)
    if points.shape[0] != capsules.shape[0] or capsules.shape[2:] != (2, 3) or radii.shape != (capsules.shape[1], 2):
        raise ValueError(f"points {points.shape}, capsules {capsules.shape} and radii {radii.shape} do not match")
    if points.size == 0 or capsules.shape[1] == 0:
        return points.copy()
    x = wp.array(points, dtype=wp.vec3, device=device)
    ends = wp.array(np.ascontiguousarray(capsules, dtype=np.float32), dtype=wp.vec3, device=device)
    wp.launch(collision.move_outside_capsules, dim=points.shape[:2], device=device,
              inputs=[x, ends, wp.array(np.ascontiguousarray(radii, dtype=np.float32), dtype=float, device=device),
                      float(thickness)])
    return x.numpy()
