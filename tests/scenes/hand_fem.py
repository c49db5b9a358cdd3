"""The hand tests' one way to pose a hand through the FEM: each pose a frame from the last, the nodes' skinning as
the warm start, every frame converged."""
import numpy as np

from scenes.hand_skeleton import hand_transforms
from sim.fem import FemInputs, FemModel, FemSettings, FemSolver


def solve(hand, poses, settings=FemSettings()):
    """A CPU FemSolver of `hand` stepped through `poses` (each 18 angles) from the rest pose."""
    model = FemModel(hand.volume.nodes, hand.volume.tets, settings, hand.volume.driven, hand.volume.embedding)
    solver = FemSolver(model, "cpu")
    last = hand_transforms(hand.skeleton, np.zeros(18))
    for angles in poses:
        now = hand_transforms(hand.skeleton, angles)
        solver.step(solver.state, FemInputs(hand.driven_targets(now), hand.node_motion(last, now)))
        assert solver.last_report.converged.all()
        last = now
    return solver
