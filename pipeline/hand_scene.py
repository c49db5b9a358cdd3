"""Stage `hand_scene`: the hand scene's mesh and volume (paper Table 4, "hand"): the procedural hand's skin,
meshed at `mesh.skin_spacing`, and the tet volume the FEM deforms, cut at `mesh.tet_spacing`, with the nodes each
bone drives and the skin's embedding (scenes/hand_shape.py), written as hand.h5 (pipeline/artifacts/hand.py).

CLI: `python -m pipeline.hand_scene SETTINGS.json OUT.h5 [--quiet]` (settings: a hand scene's simulation.json).
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from pipeline.artifacts.hand import hand_spacings, write_hand
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from scenes.hand_shape import procedural_hand


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.hand_scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="a hand scene's resolved settings (simulation.json)")
    parser.add_argument("out", help="hand.h5 to write")
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    skin_spacing, tet_spacing = hand_spacings(settings, args.settings)
    try:
        hand = procedural_hand(skin_spacing, tet_spacing)
    except ValueError as err:
        raise PipelineError(f"{args.settings}: hand: {err}") from None
    write_hand(args.out, settings, hand)
    if not args.quiet:
        vol = hand.volume
        print(f"hand: {len(hand.skin_vertices):,} skin vertices, {len(hand.skin_faces):,} triangles; "
              f"{len(vol.nodes):,} nodes, {len(vol.tets):,} tets (least dihedral angle {vol.min_dihedral_deg:.1f} "
              f"deg, least radius ratio {vol.min_radius_ratio:.3f}), {len(vol.driven):,} driven by the bones "
              f"-> {args.out}", file=sys.stderr)


if __name__ == "__main__":
    cli.run(main)
