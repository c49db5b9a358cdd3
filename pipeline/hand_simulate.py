"""Stage `hand_simulate`: sequences of the hand scene through the quasi-static FEM (sim/fem/), stepped together
as one batch of worlds: each frame the nodes within each bone move rigidly with it (the 18 joint angles posed by
scenes.hand_skeleton), the free nodes to a minimum of the stable Neo-Hookean energy (Newton's method, CG, line
search, warm-started from the last frame moved along the nodes' linear blend skinning), and the skin follows its
tets. One fem.h5 per sequence (pipeline/artifacts/hand.py): angles, skin, how each frame converged, its ms.

CLI: `python -m pipeline.hand_simulate SETTINGS.json HAND.h5 NAME OUT [NAME OUT ...] [--device D] [--quiet]`:
NAME a sequence (train_000, ..., held_out_000: scenes.sequences; what each plays: scenes.hand_motion), OUT its
fem.h5. The FEM settings are `solver.fem` (sim/fem/settings.py defaults where left out); the frame rate 1 / dt.
A frame that does not reach its residual tolerance within its Newton iterations is reported (stderr and fem.h5),
not an error; a world whose energy blows up is.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Sequence

import numpy as np
import warp as wp
from tqdm import tqdm

from pipeline.artifacts.hand import HandRun, check_hand_scene, read_hand, write_hand_run
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import mesh_fingerprint
from scenes.hand_motion import sequence_angles
from scenes.hand_shape import Hand
from scenes.hand_skeleton import hand_transforms
from sim.fem import FemInputs, FemModel, FemSettings, FemSolver
from sim.solver import UnstableSimulation


def fem_settings(settings: dict, source: str) -> FemSettings:
    try:
        return FemSettings(**settings["solver"].get("fem", {}))
    except (TypeError, ValueError) as err:
        raise PipelineError(f"{source}: solver.fem: {err}") from None


def simulate(hand: Hand, angles: np.ndarray, fem: FemSettings, device: str, quiet: bool,
             names: Sequence[str]) -> list[HandRun]:
    """Angles (F, B, 18) of B sequences stepped as B worlds; each world's run."""
    n_frames, worlds = angles.shape[:2]
    vol = hand.volume
    solver = FemSolver(FemModel(vol.nodes, vol.tets, fem, vol.driven, vol.embedding), device, worlds=worlds)
    rotations, translations = hand_transforms(hand.skeleton, angles)
    skin = np.empty((n_frames, worlds, len(hand.skin_vertices), 3), np.float32)
    skin[0] = solver.state.read_world_positions()
    residual, newton, converged = (np.zeros((n_frames, worlds)) for _ in range(3))
    converged[0] = 1
    cg, solve_ms = np.zeros(n_frames), np.zeros(n_frames)
    for f in tqdm(range(1, n_frames), desc="fem", disable=quiet, unit="frame"):
        now, last = (rotations[f], translations[f]), (rotations[f - 1], translations[f - 1])
        start = time.perf_counter()
        try:
            solver.step(solver.state, FemInputs(hand.driven_targets(now), hand.node_motion(last, now)))
        except UnstableSimulation as err:
            raise PipelineError(f"sequence {names[err.world]}: the FEM blew up ({err.cause}) at frame {f}") from None
        skin[f] = solver.state.read_world_positions()
        solve_ms[f] = (time.perf_counter() - start) * 1e3
        report = solver.last_report
        residual[f], newton[f], converged[f], cg[f] = (report.residual, report.newton_iterations, report.converged,
                                                       report.cg_iterations)
    return [HandRun(angles[:, w], skin[:, w], residual[:, w], newton[:, w].astype(np.int32), cg.astype(np.int32),
                    converged[:, w].astype(bool), solve_ms / worlds, worlds, device) for w in range(worlds)]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.hand_simulate", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="a hand scene's resolved settings (simulation.json)")
    parser.add_argument("hand", help="hand.h5 (pipeline.hand_scene)")
    parser.add_argument("runs", nargs="+", metavar="NAME OUT", help="a sequence's name and its fem.h5, repeated")
    parser.add_argument("--device", help="Warp device (cpu, cuda:0); default: the settings' device")
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    if len(args.runs) % 2:
        raise PipelineError(f"give NAME OUT pairs; got {len(args.runs)} paths")
    names, outs = args.runs[0::2], args.runs[1::2]
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    check_hand_scene(settings, args.settings)
    device = args.device or settings["device"]
    cli.check_device(device, "Warp", wp.get_cuda_device_count)
    fem = fem_settings(settings, args.settings)
    hand = read_hand(args.hand)
    fps = 1.0 / settings["solver"]["dt"]
    try:
        angles = np.stack([sequence_angles(name, settings["frames"], fps, settings["drivers"]["hand"])
                           for name in names], axis=1)
    except ValueError as err:
        raise PipelineError(f"{args.settings}: {err}") from None
    runs = simulate(hand, angles, fem, device, args.quiet, names)
    source = mesh_fingerprint(hand.skin_vertices, hand.skin_faces)
    for name, out, run in zip(names, outs, runs):
        write_hand_run(out, {**settings, "sequence": name}, run, source)
        late = np.flatnonzero(~run.converged)
        if len(late):
            print(f"{out}: {len(late)} of {len(run.converged) - 1} frames did not reach the residual tolerance "
                  f"{fem.residual_tolerance:g} (largest residual {run.residual.max():.3g}, frame "
                  f"{int(run.residual.argmax())})", file=sys.stderr)
    if not args.quiet:
        ms = runs[0].solve_ms[2:] * len(runs)
        print(f"hand_simulate: {len(runs)} sequence(s) x {len(angles) - 1} frames on {device}: median "
              f"{np.median(ms) if len(ms) else 0.0:.0f} ms a batched frame, "
              f"{np.median(ms) / len(runs) if len(ms) else 0.0:.1f} ms a hand-frame", file=sys.stderr)


if __name__ == "__main__":
    cli.run(main)
