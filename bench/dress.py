"""Dress stage speed (issue 38): a user's garment read, welded, placed and settled on the mannequin, for artists'
exports of increasing size: the procedural pants cut into panels with duplicated seam vertices, written as a
centimetre OBJ (viz.export.obj_bytes), at three resolutions up to 20k+ vertices. The
scene's settings are the pants' at the chosen profile (CPU: 4 substeps x 30 iterations, self-collision on).
Prints a markdown table of medians over --repeat runs: reading and welding alone, the whole dress stage, and the
settle's cost per frame and vertex. Usage:
  python bench/dress.py [--edges 0.16,0.05,0.0145] [--repeat 3] [--settle-frames 40] [--profile cpu]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.core.config import load_config, resolve_scene, shared_settings
from pipeline.core.meshio import load_mesh_groups
from pipeline.dress import dress
from pipeline.solvers.dress_settle import STAGES
from scenes.garment_file import garment_from_file
from scenes.garments import make_garment
from viz.export import obj_bytes

REPO = Path(__file__).resolve().parents[1]


def settings_for(path: Path, profile: str, settle_frames: int) -> dict:
    config = load_config(REPO / "workflow_config.yaml")
    config["scenes"]["bench"] = {"like": "pants", "mesh": {
        "generator": "garment_file", "file": str(path), "units": "auto", "up": "auto", "weld": 1e-4,
        "max_edge": 0.16, "remesh": False, "pins": "auto",
        "fit": {"anchor": "auto", "offset": [0.0, 0.0, 0.0], "scale": 1.0, "settle_frames": settle_frames}}}
    return shared_settings(resolve_scene(config, "bench", profile))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", default="0.16,0.05,0.0145", help="max_edge of the pants written (metres)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--settle-frames", type=int, default=40)
    parser.add_argument("--profile", default="cpu")
    parser.add_argument("--device", default="cpu", help="where the settle runs (the paper profile's is CUDA)")
    args = parser.parse_args()
    print("| file vertices | welded vertices | read + weld s | dress s | (dress - read) ms / settle frame | us / settle frame / vertex |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for edge in map(float, args.edges.split(",")):
            path = Path(folder) / f"pants_{edge}.obj"
            garment = make_garment("pants", max_edge=edge, panels=True)
            path.write_bytes(obj_bytes(garment.vertices * 100.0, garment.faces))
            settings = {**settings_for(path, args.profile, args.settle_frames), "device": args.device}
            reads, totals = [], []
            for _ in range(args.repeat):
                start = time.perf_counter()
                vertices, faces, _ = load_mesh_groups(path)
                welded = garment_from_file(vertices, faces, "auto", "auto", 1e-4, None)
                reads.append(time.perf_counter() - start)
                start = time.perf_counter()
                try:
                    dress(settings)
                except ValueError as err:     # refused: the row says why (a mesh too fine for the budget)
                    print(f"| {len(vertices)} | {len(welded.vertices)} | {reads[-1]:.2f} | refused after "
                          f"{time.perf_counter() - start:.1f} s: {err} | | |", flush=True)
                    break
                totals.append(time.perf_counter() - start)
            if len(totals) < args.repeat:
                continue
            read, total = statistics.median(reads), statistics.median(totals)
            frames = STAGES * max(1, args.settle_frames // STAGES)
            settle = (total - read) / frames
            print(f"| {len(vertices)} | {len(welded.vertices)} | {read:.2f} | {total:.2f} | {settle * 1e3:.1f} | "
                  f"{settle * 1e6 / len(welded.vertices):.1f} |", flush=True)


if __name__ == "__main__":
    main()
