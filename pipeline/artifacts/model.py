"""model.pt, written by the `train` stage: the state dict and everything needed to rebuild the network and to
recognise the operators it was trained on (docs/artifacts.md, section "model.pt"); and the file of the per-epoch
checkpoint of a running training, whose contents are model/training.py's business.

Both are read with `torch.load(weights_only=True)`, which builds tensors and plain values only: a file from
elsewhere is refused with one error, never unpickled into code. Nor may it hold more than its own size: a 3.3 MB
zip bomb once inflated to 2 GB, and a 1.4 MB file held a (10^9, 3) tensor of stride 0 over three numbers, which
evaluate materialised (7.5 GiB). torch.save stores its members uncompressed and each tensor over storage of its
own, so a member that inflates, or a tensor that needs more elements than its storage holds, is refused
(`_load`) before anything is built from it."""
from __future__ import annotations

import dataclasses
import os
import zipfile
from pathlib import Path
from typing import Any, Mapping

import torch

from model.mesh_hierarchy import MeshHierarchy
from model.networks import NetworkSpec
from model.regressors import Regressor, check_levels, input_spec, rebuild_regressor, saved_fields
from model.training import CHECKPOINT_FORMAT
from pipeline.artifacts.operators import load_hierarchy
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write

MODEL_FORMAT = "trimesh-cnn/model-2"     # 1: absolute positions only, no feature spec


def read_model_state(path: str | os.PathLike, expected_format: str, what: str) -> dict:
    """The dict a model file holds, loaded without unpickling (weights_only) on the CPU; one error naming the file
    if it is missing, unreadable or not of `expected_format` (`what` says which writer's file was expected)."""
    if not Path(path).is_file():
        raise PipelineError(f"{path}: model file does not exist")
    state = _load(path, f"{path}: not a readable model file")
    if not isinstance(state, dict) or state.get("format") != expected_format:
        raise PipelineError(f"{path}: not {what} (format {expected_format})")
    return state


def save_model(path: Path, model: Regressor, spec: NetworkSpec, mesh: MeshHierarchy,
               extra: Mapping[str, Any]) -> None:
    state = {"format": MODEL_FORMAT, "spec": dataclasses.asdict(spec), "features": dataclasses.asdict(model.spec),
             "state_dict": model.state_dict(),
             "arch_expanded": str(model.net.arch), "parameter_count": model.net.parameter_count(),
             "operators": {"fingerprint": mesh.fingerprint(), "vertex_counts": mesh.vertex_counts}, **extra}
    save_state(path, state)


def load_model(path: str | os.PathLike, operators_path: str | os.PathLike,
               device: str) -> tuple[Regressor, MeshHierarchy, dict]:
    """A trained model and the hierarchy it runs on, after checking the operators are those it was trained on.
    The network's kind decides the regressor it is wrapped in (model.regressors)."""
    state = read_model_state(path, MODEL_FORMAT, "a model written by pipeline.train")
    try:
        check_plain(state, _PLAIN_FIELDS)
        spec, weights, trained = NetworkSpec(**state["spec"]), state["state_dict"], state["operators"]
        check_plain(state, saved_fields(spec))
        inputs = input_spec(spec, state["features"])
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise PipelineError(f"{path}: damaged model file ({type(err).__name__}: {err})") from None
    mesh = load_hierarchy(operators_path, spec.conv, len(trained["vertex_counts"]))
    if mesh.vertex_counts != trained["vertex_counts"]:
        raise PipelineError(f"{operators_path}: the model in {path} was trained on a mesh hierarchy with vertex "
                            f"counts {trained['vertex_counts']}, these operators have {mesh.vertex_counts}")
    if mesh.fingerprint() != trained["fingerprint"]:
        raise PipelineError(f"{operators_path}: same vertex counts but different operator tables than the ones "
                            f"the model in {path} was trained on")
    try:
        check_levels(spec, mesh.vertex_counts)
    except ValueError as err:
        raise PipelineError(f"{path}: {err} ({operators_path})") from None
    try:
        model = rebuild_regressor(spec, inputs, weights)
    except (KeyError, ValueError, RuntimeError, IndexError) as err:
        # A failed load_state_dict's message spans lines; its type says enough.
        raise PipelineError(f"{path}: its weights do not fit the network it describes ({type(err).__name__})") \
            from None
    return model.to(device).eval(), mesh.to(device), state


# The plain values of model.pt that its readers use, and their types (a nested dict: the same for its keys).
_NUMBER = (int, float)
_PLAIN_FIELDS = {
    "spec": {"arch": str, "conv": str, "pool": str, "width": _NUMBER, "in_channels": int, "out_channels": int},
    "features": {"inputs": (list, tuple)},
    "arch_expanded": str, "parameter_count": int, "state_dict": dict,
    "operators": {"fingerprint": str, "vertex_counts": (list, tuple)},
    "training": {"epochs": int, "batch_size": int, "lr": _NUMBER, "seed": int, "device": str,
                 "loss_weights": {"l1": _NUMBER, "l2": _NUMBER, "normal": _NUMBER}},
}


def check_plain(values: dict, fields: dict, where: str = "") -> None:
    """TypeError naming the first field of `fields` that `values` lacks or holds with another type."""
    for name, kind in fields.items():
        if not isinstance(values, dict) or name not in values:
            raise TypeError(f"missing '{where}{name}'")
        if isinstance(kind, dict):
            check_plain(values[name], kind, f"{where}{name}.")
        elif not isinstance(values[name], kind) or isinstance(values[name], bool):
            raise TypeError(f"'{where}{name}' is {type(values[name]).__name__}")


def write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    save_state(path, state)


def read_checkpoint(path: Path) -> dict[str, Any] | None:
    """The training state saved at `path` by `write_checkpoint`, or None if there is none (yet, or any more:
    an identical run beside this one may have finished and removed it). Anything else at that path is refused
    rather than overwritten and later deleted: it is not this trainer's file."""
    refusal = f"{path}: not a training checkpoint ({CHECKPOINT_FORMAT}); remove it or choose another --checkpoint"
    try:
        state = _load(path, refusal)
    except FileNotFoundError:
        return None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise PipelineError(refusal)
    return state


class _Oversized(ValueError):
    """A file that would take more memory than its own size."""


def _load(path: str | os.PathLike, refusal: str) -> Any:
    """What torch.save wrote at `path`, read without unpickling and within the file's own size; `refusal` and
    the reason as one error otherwise (FileNotFoundError passes, for the checkpoint that is not there yet)."""
    try:
        _check_archive(path)
        state = torch.load(path, map_location="cpu", weights_only=True)
        _check_tensors(state)
    except FileNotFoundError:
        raise
    except _Oversized as err:
        raise PipelineError(f"{refusal} ({err})") from None
    except Exception as err:  # torch and zipfile raise many types for a foreign, damaged or code-carrying file
        raise PipelineError(f"{refusal} ({type(err).__name__})") from None
    return state


def _check_archive(path: str | os.PathLike) -> None:
    """Every member stored as torch.save stores it, so that reading it takes no more than the file's size."""
    with zipfile.ZipFile(path) as archive:
        members = archive.infolist()
    if (any(m.compress_type != zipfile.ZIP_STORED for m in members)
            or sum(m.file_size for m in members) > os.path.getsize(path)):
        raise _Oversized("compressed members, which torch.save never writes: the file may inflate far beyond "
                         "its size")


def _check_tensors(value: Any) -> None:
    """Every tensor in `value` (dicts and lists walked) dense over storage that holds all its elements; an
    expanded view (stride 0) of a few numbers becomes as large as its shape once anything computes with it."""
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, (list, tuple)):
        for item in value:
            _check_tensors(item)
    elif isinstance(value, torch.Tensor) and not (
            value.is_contiguous() and value.numel() * value.element_size() <= value.untyped_storage().nbytes()):
        raise _Oversized(f"a tensor of shape {tuple(value.shape)} is not stored element by element (an expanded "
                         f"or overlapping view)")


def save_state(path: Path, state: dict[str, Any]) -> None:
    with atomic_write(path) as f:
        torch.save(state, f)
