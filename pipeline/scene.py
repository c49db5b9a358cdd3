"""Scene stage: the low-res rest mesh, its pinned vertices with their per-frame targets, and for garment scenes
the animated mannequin (skeleton, motion, collision capsules, pose vectors, torso frames, skinning weights).

CLI: `python -m pipeline.scene SETTINGS.json OUT.h5` (settings resolved by `python -m pipeline.config`).
The scene is assembled by `scenes.registry` and written by `pipeline.artifacts.scene`; docs/artifacts.md lists
every dataset.
"""
from __future__ import annotations

import argparse
from typing import Sequence

from pipeline import cli
from pipeline.artifacts.scene import write_scene
from pipeline.config import read_settings
from pipeline.errors import PipelineError
from scenes.registry import build_scene


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON)")
    parser.add_argument("out", help="scene.h5 to write")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings)
    try:
        scene = build_scene(settings)
    except ValueError as err:
        raise PipelineError(f"scene '{settings['scene']}': {err}") from None
    write_scene(args.out, scene, settings)


if __name__ == "__main__":
    cli.run(main)
