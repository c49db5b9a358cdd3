"""Stage `hand_scene`: the hand scene's mesh and volume (paper Table 4, "hand"): the procedural hand's skin, meshed
at `mesh.skin_spacing` (`mesh.generator: hand`), or the user's own closed skin and bone file (`hand_file`:
`mesh.file`, `mesh.bones`, `mesh.units`; scenes/hand_file.py), and the tet volume the FEM deforms, cut at
`mesh.tet_spacing`, with the nodes each bone drives and the skin's embedding (scenes/hand_shape.py), written as
hand.h5 (pipeline/artifacts/hand.py).

A user's file that cannot make a hand (an open or non-manifold skin, a bone file that is no tree of the hand's
roles, a joint or bone outside the skin) is one error naming that file, and nothing is written.

CLI: `python -m pipeline.hand_scene SETTINGS.json OUT.h5 [--quiet]` (settings: a hand scene's simulation.json).
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path
from typing import Any, Sequence

import yaml

from pipeline.artifacts.hand import check_hand_scene, write_hand
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings, yaml_error
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import require_input_file
from pipeline.core.meshio import load_mesh
from scenes.garment_file import UNITS
from scenes.hand_file import file_hand, read_rig, rig_skeleton, skin_from_file
from scenes.hand_shape import Hand, procedural_hand

MAX_BONE_FILE_BYTES = 1_000_000     # a hand's ~25 joints take ~3 kB; more is no bone file


def user_hand(mesh: dict, settings_path: str) -> tuple[Hand, dict[str, Any]]:
    """The hand of a hand_file scene's files and what hand.h5 records of them; one error naming the file at fault
    (the spacing's: the settings)."""
    skin_path, bones_path = Path(mesh["file"]), Path(mesh["bones"])
    vertices, faces = load_mesh(skin_path)
    try:
        skin = skin_from_file(vertices, faces, mesh["units"])
    except ValueError as err:
        raise PipelineError(f"{skin_path}: {err}") from None
    try:
        rig = read_rig(read_bone_file(bones_path)).in_metres(UNITS[skin.units])
        skeleton = rig_skeleton(skin, rig)
    except ValueError as err:
        raise PipelineError(f"{bones_path}: {err}") from None
    try:
        hand = file_hand(skin, skeleton, mesh["tet_spacing"])
    except ValueError as err:
        raise PipelineError(f"{settings_path}: hand: {err}") from None
    attrs = {"file": str(skin_path), "bones": str(bones_path), "units": skin.units,
             "file_sha256": hashlib.sha256(skin_path.read_bytes()).hexdigest(),
             "bones_sha256": hashlib.sha256(bones_path.read_bytes()).hexdigest()}
    return hand, attrs


def read_bone_file(path: Path) -> Any:
    """A bone file parsed (YAML, which reads JSON too); one error naming it if it cannot be."""
    require_input_file(path)
    if path.stat().st_size > MAX_BONE_FILE_BYTES:
        raise PipelineError(f"{path}: {path.stat().st_size:,} bytes, beyond the {MAX_BONE_FILE_BYTES:,} of any bone "
                            f"file")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as err:
        raise PipelineError(f"{path}: cannot read the bone file ({err})") from None
    except yaml.YAMLError as err:
        raise PipelineError(yaml_error(path, err)) from None


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.hand_scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="a hand scene's resolved settings (simulation.json)")
    parser.add_argument("out", help="hand.h5 to write")
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    check_hand_scene(settings, args.settings)
    mesh = settings["mesh"]
    if mesh["generator"] == "hand_file":
        hand, attrs = user_hand(mesh, args.settings)
    else:
        try:
            hand, attrs = procedural_hand(mesh["skin_spacing"], mesh["tet_spacing"]), {}
        except ValueError as err:
            raise PipelineError(f"{args.settings}: hand: {err}") from None
    write_hand(args.out, settings, hand, attrs)
    if not args.quiet:
        vol = hand.volume
        print(f"hand: {len(hand.skin_vertices):,} skin vertices, {len(hand.skin_faces):,} triangles; "
              f"{len(vol.nodes):,} nodes, {len(vol.tets):,} tets (least dihedral angle {vol.min_dihedral_deg:.1f} "
              f"deg, least radius ratio {vol.min_radius_ratio:.3f}), {len(vol.driven):,} driven by the bones "
              f"-> {args.out}", file=sys.stderr)


if __name__ == "__main__":
    cli.run(main)
