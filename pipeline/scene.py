"""Scene stage: what every sequence of a scene shares (the low-res rest mesh, its pinned vertices, a garment
scene's skeleton and skinning), or with --sequence one sequence: all that, plus the pins' targets per frame and
what moves them (a grid scene's rod; a garment scene's animated mannequin: motion, collision capsules, pose
vectors, torso frames).

CLI: `python -m pipeline.scene SETTINGS.json OUT.h5 [--sequence NAME]` (settings resolved by
`python -m pipeline.settings`; NAME e.g. train_000, held_out_000 or a library window's train_001-01-01_w00, see
scenes/sequences.py). The scene is assembled by `scenes.registry` and written by `pipeline.artifacts.scene`;
docs/artifacts.md lists every dataset. A library window that cannot be played (its file cannot be read or mapped,
or it drives limbs through each other) is dropped: its scene file says why (pipeline.core.h5.write_dropped), the
later stages pass the sequence over, and the stage succeeds.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from pipeline.artifacts.dressed import read_dressed_garment
from pipeline.artifacts.scene import write_dropped_scene, write_scene, write_scene_rest
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from scenes.library import UnusableWindow, find_window
from scenes.registry import build_rest, build_scene
from scenes.sequences import library_of, window_key
from scenes.skeleton import default_skeleton


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON)")
    parser.add_argument("out", help="scene.h5 to write")
    parser.add_argument("--sequence", help="write this sequence (train_000, ..., held_out_000, ...) instead of "
                                           "what the sequences share")
    parser.add_argument("--dressed", help="a garment_file scene's dressed.h5 (python -m pipeline.dress): its rest "
                                          "mesh and pins")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    if (settings["mesh"]["generator"] == "garment_file") != (args.dressed is not None):
        raise PipelineError(f"{args.settings}: --dressed is given exactly for a garment_file scene (mesh.generator "
                            f"here: '{settings['mesh']['generator']}')")
    dressed = None if args.dressed is None else read_dressed_garment(args.dressed, default_skeleton().n_parts)
    where = f"scene '{settings['scene']}'" + (f" sequence '{args.sequence}'" if args.sequence else "")
    try:
        if args.sequence is None:
            write_scene_rest(args.out, build_rest(settings, dressed), settings)
            return
        try:
            scene = build_scene(settings, args.sequence, dressed)
        except UnusableWindow as err:      # one clip of a library: its sequence is dropped, the run goes on
            window = find_window(library_of(settings), window_key(args.sequence))
            write_dropped_scene(args.out, build_rest(settings, dressed), args.sequence, str(err), window.describe(),
                                settings)
            print(f"{where}: dropped: {err}", file=sys.stderr)
            return
        write_scene(args.out, scene, settings)
    except ValueError as err:
        raise PipelineError(f"{where}: {err}") from None


if __name__ == "__main__":
    cli.run(main)
