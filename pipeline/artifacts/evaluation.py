"""eval.h5, written by the `evaluate` stage: errors of the network and of its predictor alone, per-frame errors,
predicted positions, inference times and, for a dataset of motion-library windows, the errors per motion category
and per subject (docs/artifacts.md, section "eval.h5")."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from typing import Any, Iterator, Mapping

import h5py
import numpy as np

from model.scoring import WHO
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, config_of, open_artifact, read

STAGE = "evaluate"
BY_KIND = "by_kind"      # errors per motion category and per subject of a dataset with motion-library windows
GROUPINGS = ("category", "subject")
TERMS = ("l1", "l2")     # per frame and per group; WHO: the network, its predictor alone
FUSED_MS = "inference_ms_fused"      # the fused bf16 network's times, written where it was timed (CUDA)


@dataclasses.dataclass(frozen=True)
class GroupErrors:
    """The errors of the network and of its predictor alone over the frames of each group of one grouping (the
    library's motion categories, or its subjects), per split."""

    labels: tuple[str, ...]                              # (G,) the groups
    frames: dict[str, np.ndarray]                        # split -> (G,) int64 each group's frames in it
    errors: dict[str, dict[str, dict[str, np.ndarray]]]  # split -> network/predictor -> l1/l2 -> (G,) float64,
                                                         # NaN for a group without frames in the split


@dataclasses.dataclass(frozen=True)
class FusedTiming:
    """The fused bf16 network's ms per timed frame (model.fused_network: CUDA only; the same frames and warm-up
    as the fp32 deployment path's) and its error against that path: the largest |fused - fp32| displacement over
    the timed frames, over the largest |fp32| displacement."""
    ms: np.ndarray              # (T,)
    error: float
    path: str                   # how it ran, in words


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """What the evaluation measured."""

    errors: dict[str, dict[str, dict[str, float]]]   # "network"/"predictor" -> split -> term (l1, l2, ...) -> value
    per_frame: dict[str, dict[str, np.ndarray]]      # "network"/"predictor" -> "l1"/"l2" -> (F,) error per frame
    predicted: np.ndarray | None                     # (F, V, 3) predicted high-res positions, dataset's frame;
                                                     # None: not stored (errors only, for grids of evaluations),
                                                     # or written a run of frames at a time (evaluation_output)
    inference_ms: np.ndarray                         # (T,) ms per timed frame
    inference_frames: np.ndarray                     # (T,) the timed frame ids
    device: str                                      # where it ran, in words (e.g. "cpu, 2 threads")
    warmup_runs: int                                 # untimed runs before the timed ones
    parameter_count: int
    trained_frames: int                              # the frames the network trained on (model.pt's training)
    by_kind: dict[str, GroupErrors] = dataclasses.field(default_factory=dict)   # grouping -> errors; empty: a
                                                                                # dataset without library windows
    fused: FusedTiming | None = None    # None: not timed (the CPU, where it does not run; a decoder)
    predictor: str = "the predictor"    # what the predictor is, in words (the task's: "Loop subdivision", ...)
    phase_seconds: dict[str, float] = dataclasses.field(default_factory=dict)   # the stage's wall time by phase


def write_evaluation(path: str | os.PathLike, config: Mapping[str, Any], evaluation: Evaluation) -> None:
    """eval.h5 of an evaluation whose predicted positions (if stored) are one array."""
    stored = evaluation.predicted
    with evaluation_output(path, config, None if stored is None else stored.shape) as out:
        if stored is not None:
            out.write_predicted(0, stored)
        out.finish(evaluation)


@contextlib.contextmanager
def evaluation_output(path: str | os.PathLike, config: Mapping[str, Any],
                      predicted_shape: tuple[int, ...] | None) -> Iterator[EvaluationOutput]:
    """eval.h5 written as the evaluation goes (through h5.atomic_h5: it appears only if the block succeeds):
    the predicted positions of shape `predicted_shape` (F, V, 3) (None: not stored) a run of frames at a time,
    as they are made, then the rest (`EvaluationOutput.finish`)."""
    with atomic_h5(path, STAGE, config) as f:
        out = EvaluationOutput(f, predicted_shape)
        yield out
        if not out.finished:
            raise RuntimeError(f"{path}: the evaluation was not finished")


class EvaluationOutput:
    """An eval.h5 being written (evaluation_output)."""

    def __init__(self, f: h5py.File, predicted_shape: tuple[int, ...] | None):
        self._f, self._rows, self.finished = f, 0, False
        self._frames = None if predicted_shape is None else predicted_shape[0]
        if predicted_shape is not None:
            # Contiguous, as one array made it: the rows are written in order, each once.
            f.create_dataset("predicted", predicted_shape, np.float32)
            f["predicted"].attrs["meaning"] = "predicted high-res positions per frame (F, V, 3), dataset's frame"

    def write_predicted(self, first: int, positions: np.ndarray) -> None:
        """The predicted positions (n, V, 3) of the frames [first, first + n), the rows after those written."""
        if self._frames is None or first != self._rows or first + len(positions) > self._frames:
            raise ValueError(f"predicted rows {first}-{first + len(positions) - 1} after {self._rows} of "
                             f"{self._frames} rows")
        self._f["predicted"][first:first + len(positions)] = positions.astype(np.float32, copy=False)
        self._rows += len(positions)

    def finish(self, evaluation: Evaluation) -> None:
        """Everything else the evaluation measured (its `predicted` is not read: the rows written are)."""
        if self._frames is not None and self._rows != self._frames:
            raise ValueError(f"{self._rows} of {self._frames} frames' predicted positions written")
        _write_results(self._f, evaluation, self._frames is not None)
        self.finished = True


def _write_results(f: h5py.File, evaluation: Evaluation, predictions_stored: bool) -> None:
    for who, splits in evaluation.errors.items():
        for split, values in splits.items():
            for term, value in values.items():
                f.create_dataset(f"errors/{who}/{split}/{term}", data=np.float64(value))
    f["errors"].attrs["meaning"] = ("split-wide L1 (eq. 4), L2 (eq. 5), Ln (eq. 6) and the training loss's "
                                    "weighted total; network = predictor + network output, predictor = "
                                    f"{evaluation.predictor} alone")
    f.attrs["predictor"] = evaluation.predictor
    f["errors"].attrs["unit"] = "scene units (~m); Ln dimensionless"
    for who, values in evaluation.per_frame.items():
        for term, per_frame in values.items():
            f.create_dataset(f"per_frame/{who}_{term}", data=per_frame.astype(np.float64))
    f.attrs["predictions_stored"] = predictions_stored
    f.create_dataset("inference_ms", data=evaluation.inference_ms)
    f.create_dataset("inference_frames", data=np.asarray(evaluation.inference_frames, dtype=np.int64))
    f.attrs.update(device=evaluation.device, inference_ms_median=float(np.median(evaluation.inference_ms)),
                   warmup_runs=evaluation.warmup_runs, parameter_count=evaluation.parameter_count,
                   trained_frames=evaluation.trained_frames,
                   timing="input features and network, batch of one frame")
    if evaluation.phase_seconds:
        f.attrs["phase_seconds"] = json.dumps(evaluation.phase_seconds)
        f.attrs["phase_seconds_meaning"] = (
            "the evaluate stage's wall seconds by phase, in order: load (from the stage's start after its imports: "
            "dataset, model, frames onto the device), score (every frame through the network and the predictor, "
            "the scored frames' OBJ export), time (inference timing: eager, the deployment path and, on CUDA "
            "unless --no-fused-timing, the fused network, captures and kernel compiles included), pictures, videos, exports and report (up to "
            "this file; the report's writing follows)")
    if evaluation.fused is not None:
        f.create_dataset(FUSED_MS, data=np.asarray(evaluation.fused.ms, dtype=np.float64))
        f[FUSED_MS].attrs.update(meaning="ms per timed frame (inference_frames) of the fused bf16 network, "
                                         "timed as inference_ms; absent: not timed (it runs on CUDA only)",
                                 path=evaluation.fused.path, error_vs_fp32=evaluation.fused.error,
                                 error_meaning="largest |fused - fp32| displacement over the timed frames over the "
                                               "largest |fp32| displacement")
    for grouping, groups in evaluation.by_kind.items():
        _write_groups(f, f"{BY_KIND}/{grouping}", groups)
    if evaluation.by_kind:
        f[BY_KIND].attrs["meaning"] = ("per grouping (the library's manifest categories, its subjects): the "
                                       "groups' labels and, per split, each group's frames and the L1 and L2 "
                                       "of the network and of the predictor alone over them (scene units; NaN: "
                                       "no frame); gain = predictor / network")


def _write_groups(f, where: str, groups: GroupErrors) -> None:
    f.create_dataset(f"{where}/labels", data=np.array([label.encode() for label in groups.labels], dtype="S"))
    for split, frames in groups.frames.items():
        f.create_dataset(f"{where}/{split}/frames", data=np.asarray(frames, dtype=np.int64))
        for who in WHO:
            for term in TERMS:
                f.create_dataset(f"{where}/{split}/{who}_{term}",
                                 data=np.asarray(groups.errors[split][who][term], dtype=np.float64))


def read_errors_by_kind(path: str | os.PathLike) -> dict[str, GroupErrors]:
    """The errors per motion category and per subject an evaluation wrote (empty: it wrote none, its dataset had
    no library windows): grouping -> GroupErrors."""
    with open_artifact(path) as f:
        if BY_KIND not in f:
            return {}
        try:
            return {grouping: _read_groups(f, f"{BY_KIND}/{grouping}") for grouping in GROUPINGS}
        except (KeyError, TypeError, ValueError, AttributeError, UnicodeDecodeError):
            raise PipelineError(f"{path}: '{BY_KIND}' must hold, per grouping {', '.join(GROUPINGS)}, texts "
                                f"'labels' and per split 'frames' and the network's and predictor's l1 and l2, "
                                f"one per label") from None


def _read_groups(f, where: str) -> GroupErrors:
    labels = tuple(label.decode() for label in f[f"{where}/labels"][()])
    splits = [name for name in f[where] if name != "labels"]
    frames = {split: np.asarray(f[f"{where}/{split}/frames"][()], dtype=np.int64) for split in splits}
    errors = {split: {who: {term: np.asarray(f[f"{where}/{split}/{who}_{term}"][()], dtype=np.float64)
                            for term in TERMS} for who in WHO} for split in splits}
    for split, by_who in errors.items():
        counted = frames[split] > 0
        values = [a for by_term in by_who.values() for a in by_term.values()]
        if frames[split].shape != (len(labels),) or np.any(frames[split] < 0) \
                or any(a.shape != (len(labels),) or not np.all(np.isfinite(a[counted]) & (a[counted] >= 0))
                       for a in values):
            raise ValueError(where)
    return GroupErrors(labels, frames, errors)


def read_errors(path: str | os.PathLike) -> dict[str, dict[str, dict[str, float]]]:
    """The split-wide errors an evaluation wrote: "network"/"predictor" -> split -> term -> value, each split
    with at least its l1 and l2."""
    with open_artifact(path) as f:
        try:
            errors = {who: {split: {term: float(read(f, f"errors/{who}/{split}/{term}")) for term in ("l1", "l2")}
                            for split in f[f"errors/{who}"]}
                      for who in ("network", "predictor")}
        except (KeyError, TypeError, ValueError):
            raise PipelineError(f"{path}: 'errors/network' and 'errors/predictor' must hold a group per split with "
                                f"scalars l1 and l2: not an eval.h5 of pipeline.evaluate") from None
    if set(errors["network"]) != set(errors["predictor"]):
        raise PipelineError(f"{path}: the network and the predictor were evaluated on different splits")
    return errors


@dataclasses.dataclass(frozen=True)
class NetworkTiming:
    """What an eval.h5 says of its network's speed and size."""
    inference_ms: np.ndarray    # (T,) ms per timed frame on the deployment path
    device: str                 # where it ran, in words
    params: int                 # learnable parameters
    name: str                   # "<conv> x<width>", from the recorded model spec
    fused: FusedTiming | None   # the fused bf16 network's, where it was timed (CUDA); else None


def read_network_timing(path: str | os.PathLike) -> NetworkTiming:
    """The timed frames' ms, the device, the parameter count and a short name of the evaluated network."""
    with open_artifact(path) as f:
        times = read(f, "inference_ms", np.float64)
        spec = config_of(f).get("model_spec", {})
        try:
            device = str(f.attrs["device"])
            name = f"{spec['conv']} x{float(spec['width']):g}"
        except (KeyError, TypeError, ValueError) as err:
            raise PipelineError(f"{path}: {err} missing or malformed: not an eval.h5 of pipeline.evaluate") from None
        fused = None
        if FUSED_MS in f:
            fused_ms = read(f, FUSED_MS, np.float64)
            attrs = f[FUSED_MS].attrs
            error = float(attrs.get("error_vs_fp32", np.nan))
            if fused_ms.shape != times.shape or not np.all(np.isfinite(fused_ms)) or not np.isfinite(error):
                raise PipelineError(f"{path}: '{FUSED_MS}' must hold finite ms of each timed frame and a finite "
                                    f"attribute 'error_vs_fp32'")
            fused = FusedTiming(fused_ms, error, str(attrs.get("path", "")))
    if times.ndim != 1 or len(times) == 0 or not np.all(np.isfinite(times)):
        raise PipelineError(f"{path}: 'inference_ms' must hold the finite ms of at least one timed frame")
    return NetworkTiming(times, device, read_parameter_count(path), name, fused)


def read_trained_frames(path: str | os.PathLike) -> int:
    """The frames the evaluated network trained on (the attribute `trained_frames`)."""
    return _count_attr(path, "trained_frames", 1, " (or one made before it recorded them: evaluate again)")


def read_parameter_count(path: str | os.PathLike) -> int:
    """The evaluated network's parameter count (the attribute `parameter_count`)."""
    return _count_attr(path, "parameter_count", 0)


def _count_attr(path: str | os.PathLike, name: str, least: int, hint: str = "") -> int:
    """An eval.h5's whole-number attribute `name`, at least `least`; one error naming it otherwise."""
    with open_artifact(path) as f:
        value = f.attrs.get(name)
    if not isinstance(value, (int, np.integer)) or value < least:
        raise PipelineError(f"{path}: attribute '{name}' must be an integer >= {least}: not an eval.h5 of "
                            f"pipeline.evaluate{hint}")
    return int(value)
