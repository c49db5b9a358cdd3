"""Scene stage: what every sequence of a scene shares (the low-res rest mesh, its pinned vertices, a garment
scene's skeleton and skinning), or with --sequence one sequence: all that, plus the pins' targets per frame and
what moves them (a grid scene's rod; a garment scene's animated mannequin: motion, collision capsules, pose
vectors, torso frames).

CLI: `python -m pipeline.scene SETTINGS.json OUT.h5 [--sequence NAME]` (settings resolved by
`python -m pipeline.settings`; NAME e.g. train_000 or held_out_000, see scenes/sequences.py). The scene is
assembled by `scenes.registry` and written by `pipeline.artifacts.scene`; docs/artifacts.md lists every dataset.
"""
from __future__ import annotations

import argparse
from typing import Sequence

from pipeline.artifacts.scene import write_scene, write_scene_rest
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from scenes.registry import build_rest, build_scene


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON)")
    parser.add_argument("out", help="scene.h5 to write")
    parser.add_argument("--sequence", help="write this sequence (train_000, ..., held_out_000, ...) instead of "
                                           "what the sequences share")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    where = f"scene '{settings['scene']}'" + (f" sequence '{args.sequence}'" if args.sequence else "")
    try:
        if args.sequence is None:
            write_scene_rest(args.out, build_rest(settings), settings)
        else:
            write_scene(args.out, build_scene(settings, args.sequence), settings)
    except ValueError as err:
        raise PipelineError(f"{where}: {err}") from None


if __name__ == "__main__":
    cli.run(main)
