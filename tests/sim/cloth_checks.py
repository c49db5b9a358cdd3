"""Measures and scenes of a cloth the solver tests share (imported by package path: tests.sim.cloth_checks)."""
import numpy as np

from geometry.mesh import unique_edges
from scenes.capsules import capsules_world
from scenes.garments import make_garment
from scenes.grid import grid_cloth
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, make_motion
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings


class FakeGpu:
    """What the frame kernel's choice (frame_kernel_for, default_layout, checked_layout) reads of a device: a GPU
    of compute capability arch / 10 without one."""
    is_cuda = True

    def __init__(self, arch, sm_count=132):
        self.arch, self.sm_count = arch, sm_count

    def __str__(self):
        return f"sm_{self.arch}"


def edge_ratios(x, rest, faces):
    """Each edge's length at positions x over its rest length."""
    e = unique_edges(faces)
    return np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)


def stacked_sheets():
    """A 0.5 x 0.5 sheet pinned along its border, and a smaller free one 3 cm above it."""
    bottom, bottom_faces = grid_cloth(0.5, 0.5, 0.06, plane="xz", origin=(-0.25, 1.0, -0.25))
    top, top_faces = grid_cloth(0.4, 0.4, 0.06, plane="xz", origin=(-0.2, 1.03, -0.2))
    vertices = np.concatenate([bottom, top])
    faces = np.concatenate([bottom_faces, top_faces + len(bottom)])
    border = np.flatnonzero(np.isclose(np.abs(bottom[:, 0]), 0.25) | np.isclose(np.abs(bottom[:, 2]), 0.25))
    return vertices, faces, border, len(bottom), bottom_faces


def contact_scene(device, sweep_lanes=None, frame_kernel="auto", **solver):
    """Stacked sheets draped over a capsule that moves: body contact, friction and self-contact all active; 30
    frames' positions and the solver (`solver`: more of ClothSolver's arguments)."""
    vertices, faces, _, _, _ = stacked_sheets()
    radii = np.array([[0.08, 0.06]])

    def capsule(frame):
        return np.array([[[-0.3, 0.9 + 0.002 * frame, 0.0], [0.3, 0.9, 0.01 * frame]]])

    settings = SolverSettings(substeps=2, iterations=10, body_collision=True, self_collision=True,
                              frame_kernel=frame_kernel)
    solver = ClothSolver(ClothModel(vertices, faces, settings, np.zeros(0, int), capsule_radii=radii), device,
                         initial_inputs=FrameInputs(capsules=capsule(0)), sweep_lanes=sweep_lanes, **solver)
    positions = []
    for frame in range(1, 31):
        solver.step(solver.state, FrameInputs(capsules=capsule(frame)))
        positions.append(solver.state.read_positions())
    return np.array(positions), solver


def coarse_pants_drives(frames: int, motions: tuple[str, ...]):
    """Coarse pants on the mannequin and, per motion, the capsules and attachment-pin targets of every frame."""
    skel = default_skeleton()
    garment = make_garment("pants", skel, max_edge=0.1)
    ids = garment.attachment
    drives = []
    for kind in motions:
        state = body_state(skel, make_motion(kind, frames + 1, settle_frames=0, blend_frames=4))
        a, b, ra, rb = capsules_world(skel, state.transforms)
        targets = linear_blend_skinning(garment.vertices[ids], garment.attachment_part[:, None],
                                        np.ones((len(ids), 1)), rest_transforms(skel), state.transforms)
        drives.append((np.stack([a, b], axis=2), targets))
    radii = np.stack([ra[0], rb[0]], axis=1)
    return garment, ids, radii, drives


def run_worlds(garment, ids, radii, drives, settings, frames, device="cpu", **solver):
    """(B, frames, V, 3) positions of len(drives) worlds stepped together, and the solver (`solver`: more of
    ClothSolver's arguments)."""
    capsules = np.stack([c for c, _ in drives])
    targets = np.stack([t for _, t in drives])
    solver = ClothSolver(ClothModel(garment.vertices, garment.faces, settings, ids, capsule_radii=radii), device,
                         worlds=len(drives), initial_inputs=FrameInputs(capsules=capsules[:, 0]), **solver)
    stepped = []
    for f in range(1, frames + 1):
        solver.step(solver.state, FrameInputs(pin_targets=targets[:, f], capsules=capsules[:, f]))
        stepped.append(solver.state.read_world_positions())
    return np.stack(stepped, axis=1), solver
