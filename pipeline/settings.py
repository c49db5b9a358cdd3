"""Stage `settings`: one scene's resolved settings → settings.json (defaults + scene + profile overlay, validated
against workflow/config.schema.yaml; pipeline.core.config says how).

    python -m pipeline.settings CONFIG.yaml SCENE OUT.json [--profile P] [--device D]

writes the resolved settings as settings.json holds them and prints the scene's sequence names.
"""
from __future__ import annotations

import argparse
from typing import Sequence

from pipeline.core import cli
from pipeline.core.config import load_config, resolve_scene, shared_settings, write_settings
from scenes.sequences import sequence_names


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.settings", description=__doc__.splitlines()[0])
    parser.add_argument("config", help="workflow_config.yaml")
    parser.add_argument("scene")
    parser.add_argument("out", help="resolved settings (JSON)")
    parser.add_argument("--profile", help="overlay to apply (default: the config's `profile`)")
    parser.add_argument("--device", help="override the device (cpu, cuda:0)")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    settings = resolve_scene(config, args.scene, args.profile, args.device, args.config)
    write_settings(shared_settings(settings), args.out)
    print(" ".join(sequence_names(settings)))


if __name__ == "__main__":
    cli.run(main)
