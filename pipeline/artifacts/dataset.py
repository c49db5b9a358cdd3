"""dataset.h5, written by the `dataset` stage: the cloth-upsampling learning problem (paper Table 2) and its
train/test/held-out split (docs/artifacts.md, section "dataset.h5"); read back by `train` and `evaluate`."""
from __future__ import annotations

import dataclasses
import hashlib
import os
from typing import Any, Mapping

import numpy as np

from pipeline.artifacts.h5 import atomic_h5, open_artifact, read
from pipeline.errors import PipelineError

STAGE = "dataset"
SPLIT_MEANING = ("train: frames trained on; test: a seeded random share of the other frames of the same motions; "
                 "held_out: every frame of the clips named in attr held_out_clips (unseen motion; may be empty)")


@dataclasses.dataclass(frozen=True)
class UpsamplingProblem:
    """Input (= predictor) and target of every frame, in the dataset's reference frame, with the meshes."""

    inputs: np.ndarray           # (F, V_high, 3) float32, Loop-subdivided low-res positions S x_low
    targets: np.ndarray          # (F, V_high, 3) float32, displacements x_high - S x_low
    faces: np.ndarray            # (T_high, 3) high-res faces
    rest_vertices: np.ndarray    # (V_high, 3) float64 subdivided rest mesh
    low_positions: np.ndarray    # (F, V_low, 3) float32
    low_faces: np.ndarray        # (T_low, 3)


@dataclasses.dataclass(frozen=True)
class Split:
    """Frame ids of each split."""

    train: np.ndarray
    test: np.ndarray
    held_out: np.ndarray         # every frame of the clips `held_out_clips` (may be empty)
    held_out_clips: tuple[str, ...]


def write_dataset(path: str | os.PathLike, config: Mapping[str, Any], problem: UpsamplingProblem, split: Split,
                  frame: str, seed: int, test_fraction: float) -> None:
    with atomic_h5(path, STAGE, config) as f:
        f.create_dataset("input", data=problem.inputs.astype(np.float32))
        f.create_dataset("target", data=problem.targets.astype(np.float32))
        f.create_dataset("faces", data=problem.faces.astype(np.int32))
        f.create_dataset("rest_vertices", data=problem.rest_vertices.astype(np.float64))
        f.create_dataset("low/positions", data=problem.low_positions.astype(np.float32))
        f.create_dataset("low/faces", data=problem.low_faces.astype(np.int32))
        f["predictor"] = f["input"]          # a hard link: Table 2's predictor is the input itself
        f.create_dataset("split/train", data=split.train.astype(np.int64))
        f.create_dataset("split/test", data=split.test.astype(np.int64))
        f.create_dataset("split/held_out", data=split.held_out.astype(np.int64))
        f["split"].attrs["meaning"] = SPLIT_MEANING
        f["split"].attrs["held_out_clips"] = ",".join(split.held_out_clips)
        f.attrs.update(problem="cloth upsampling (paper Table 2)", frame=frame, n_frames=len(problem.inputs),
                       n_vertices=problem.inputs.shape[1], split_seed=seed, test_fraction=test_fraction)
        f["input"].attrs["meaning"] = "Loop-subdivided low-res positions S x_low, per frame (F, V_high, 3)"
        f["target"].attrs["meaning"] = "displacement x_high - S x_low, per frame (F, V_high, 3)"


@dataclasses.dataclass(frozen=True)
class LearningData:
    """The dataset artifact's arrays: inputs (= predictor) and target displacements, faces, split."""

    inputs: np.ndarray
    targets: np.ndarray
    faces: np.ndarray
    train: np.ndarray
    test: np.ndarray
    fingerprint: str
    held_out: np.ndarray   # frames of motions never trained on (may be empty)
    frame: str = "world"   # reference frame of the positions
    held_out_clips: str = ""   # comma-separated motion clips of `held_out`

    def splits(self) -> dict[str, np.ndarray]:
        """The non-empty splits by name."""
        named = {"train": self.train, "test": self.test, "held_out": self.held_out}
        return {name: ids for name, ids in named.items() if len(ids)}


def load_dataset(path: str | os.PathLike) -> LearningData:
    with open_artifact(path) as f:
        inputs, targets = read(f, "input", np.float32), read(f, "target", np.float32)
        faces = read(f, "faces", np.int64)
        train, test = read(f, "split/train", np.int64), read(f, "split/test", np.int64)
        held_out = read(f, "split/held_out", np.int64) if "split/held_out" in f else np.zeros(0, np.int64)
        frame = str(f.attrs.get("frame", "world"))
        held_out_clips = str(f["split"].attrs.get("held_out_clips", ""))
    if inputs.shape != targets.shape or inputs.ndim != 3:
        raise PipelineError(f"{path}: 'input' {inputs.shape} and 'target' {targets.shape} must both be (F, V, 3)")
    every = np.concatenate([train, test, held_out])
    if len(train) == 0 or len(test) == 0 or len(np.unique(every)) != len(every) or every.max() >= len(inputs):
        raise PipelineError(f"{path}: 'split/train', 'split/test' (and 'split/held_out') must be disjoint frame ids, "
                            f"train and test non-empty")
    digest = hashlib.sha256(inputs.tobytes())
    digest.update(targets.tobytes())
    digest.update(train.tobytes())
    return LearningData(inputs, targets, faces, train, test, digest.hexdigest(), held_out, frame, held_out_clips)


def read_low_res(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The low-res positions (F, V_low, 3) float64 and faces int64 the dataset was made from."""
    with open_artifact(path) as f:
        return read(f, "low/positions", np.float64), read(f, "low/faces", np.int64)
