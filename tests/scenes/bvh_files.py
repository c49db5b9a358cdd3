"""Small BVH files written by the tests of the importer and the retargeting (imported by name, like
tests/model/model_meshes.py)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

POSITIONS = ("Xposition", "Yposition", "Zposition")


@dataclass
class Joint:
    """One joint of a BVH hierarchy; `rotation_order` such as "ZXY" lists its rotation channels (none if empty)."""
    name: str
    parent: int
    offset: tuple[float, float, float]
    rotation_order: str = "ZXY"
    has_position: bool = False
    end_site: tuple[float, float, float] | None = None

    @property
    def channels(self) -> tuple[str, ...]:
        return (POSITIONS if self.has_position else ()) + tuple(f"{axis}rotation" for axis in self.rotation_order)


def bvh_text(joints: list[Joint], frames: np.ndarray, frame_time: float) -> str:
    """A BVH file of `joints` (parents first, joint 0 the root) and channel values (F, C) in joint order."""
    lines = ["HIERARCHY"]

    def block(j: int, depth: int) -> None:
        pad, joint = "\t" * depth, joints[j]
        lines.append(f"{pad}{'ROOT' if joint.parent < 0 else 'JOINT'} {joint.name}")
        lines.append(pad + "{")
        lines.append(f"{pad}\tOFFSET {' '.join(f'{v:.9g}' for v in joint.offset)}")
        lines.append(f"{pad}\tCHANNELS {len(joint.channels)} {' '.join(joint.channels)}")
        for child in (k for k, other in enumerate(joints) if other.parent == j):
            block(child, depth + 1)
        if joint.end_site is not None:
            lines.extend([f"{pad}\tEnd Site", pad + "\t{",
                          f"{pad}\t\tOFFSET {' '.join(f'{v:.9g}' for v in joint.end_site)}", pad + "\t}"])
        lines.append(pad + "}")

    block(0, 0)
    lines += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time:.9g}"]
    lines += [" ".join(f"{v:.9g}" for v in row) for row in np.atleast_2d(frames)]
    return "\n".join(lines) + "\n"


def write_bvh(path: Path, joints: list[Joint], frames: np.ndarray, frame_time: float = 1 / 120) -> Path:
    path.write_text(bvh_text(joints, frames, frame_time))
    return path
