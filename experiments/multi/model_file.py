"""results/multi/model.pt, written by `experiments.multi train`: one upsampling network trained on several garments
(docs/artifacts.md, section "multi/model.pt"): the shared weights and normalisation once, and per garment its
mesh constants and the operators and dataset it was trained on; and the garment views, a model.pt of
pipeline.train's format per garment (`save_garment_view`), which `evaluate`, `export_model` and deploy/ run as
any scene's model.

Written and read as model.pt is (pipeline.artifacts.model): tensors and plain values only, read back with
`torch.load(weights_only=True)`, so a file from elsewhere is refused with one error, never unpickled into code.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Mapping

import torch

from model.feature_regressor import FeatureSpec
from model.mesh_hierarchy import MeshHierarchy
from model.multi_mesh import MultiMeshRegressor
from model.networks import NetworkSpec, build_network
from pipeline.artifacts.model import check_plain, read_model_state, save_model, save_state
from pipeline.core.errors import PipelineError

MULTI_FORMAT = "trimesh-cnn/multi-model-1"
NORMALISATION = ("input_offset", "input_scale", "output_scale")     # FeatureRegressor's buffers, shared

_NUMBER = (int, float)
_PLAIN_FIELDS = {
    "spec": {"arch": str, "conv": str, "pool": str, "width": _NUMBER, "in_channels": int, "out_channels": int},
    "features": {"inputs": (list, tuple), "input_frame": str, "output_frame": str, "frame_tangent": str},
    "arch_expanded": str, "parameter_count": int, "state_dict": dict, "normalisation": dict, "garments": dict,
    "training": {"epochs": int, "batch_size": int, "lr": _NUMBER, "seed": int, "device": str,
                 "loss_weights": {"l1": _NUMBER, "l2": _NUMBER, "normal": _NUMBER}},
}
_GARMENT_FIELDS = {"faces": torch.Tensor, "rest": torch.Tensor, "dataset_fingerprint": str,
                   "operators": {"fingerprint": str, "vertex_counts": (list, tuple)}}


def save_multi_model(path: str | os.PathLike, model: MultiMeshRegressor, spec: NetworkSpec,
                     meshes: Mapping[str, MeshHierarchy], dataset_fingerprints: Mapping[str, str],
                     training: Mapping[str, Any]) -> None:
    """The multi-garment model at `path` (on the CPU); `meshes` and `dataset_fingerprints` by garment name."""
    first = model.part(model.names[0])
    garments = {name: {"faces": part.features.faces.cpu(), "rest": part.features.rest.cpu(),
                       "dataset_fingerprint": dataset_fingerprints[name],
                       "operators": {"fingerprint": meshes[name].fingerprint(),
                                     "vertex_counts": meshes[name].vertex_counts}}
                for name, part in model.parts.items()}
    state = {"format": MULTI_FORMAT, "spec": dataclasses.asdict(spec), "features": dataclasses.asdict(model.spec),
             "state_dict": {k: v.cpu() for k, v in model.net.state_dict().items()},
             "normalisation": {name: getattr(first, name).cpu() for name in NORMALISATION},
             "arch_expanded": str(model.net.arch), "parameter_count": model.net.parameter_count(),
             "garments": garments, "training": dict(training)}
    save_state(Path(path), state)


def load_multi_model(path: str | os.PathLike) -> tuple[MultiMeshRegressor, dict]:
    """The multi-garment model of `path` on the CPU, and the file's contents."""
    state = read_model_state(path, MULTI_FORMAT, "a multi-garment model written by experiments.multi")
    try:
        check_plain(state, _PLAIN_FIELDS)
        for name, garment in state["garments"].items():
            check_plain(garment, _GARMENT_FIELDS, f"garments.{name}.")
        spec, features = NetworkSpec(**state["spec"]), FeatureSpec(**state["features"])
        meshes = {name: (g["faces"].numpy(), g["rest"].numpy()) for name, g in state["garments"].items()}
        model = MultiMeshRegressor(build_network(spec), features, meshes)
        model.net.load_state_dict(state["state_dict"])
        for part in model.parts.values():
            for name in NORMALISATION:
                getattr(part, name).copy_(state["normalisation"][name])
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError) as err:
        # A failed load_state_dict's message spans lines; its type says enough.
        raise PipelineError(f"{path}: damaged multi-garment model file ({type(err).__name__})") from None
    return model.eval(), state


def trained_operators(path: str | os.PathLike, state: dict, garment: str) -> dict:
    """What the model of `path` (its contents `state`) records of the operators it was trained with for
    `garment`: fingerprint and vertex counts; one error for a garment it was not trained on."""
    if garment not in state["garments"]:
        raise PipelineError(f"{path}: trained on garments {', '.join(state['garments'])}; not on '{garment}'")
    return state["garments"][garment]["operators"]


def check_garment_operators(path: str | os.PathLike, state: dict, garment: str, mesh: MeshHierarchy,
                            operators_path: str | os.PathLike) -> None:
    """One error unless `garment` is one the model of `path` was trained on and `mesh` (read from
    `operators_path`) the operators it was trained with there."""
    trained = trained_operators(path, state, garment)
    if mesh.vertex_counts != list(trained["vertex_counts"]):
        raise PipelineError(f"{operators_path}: the model in {path} was trained on garment '{garment}' with a mesh "
                            f"hierarchy of vertex counts {list(trained['vertex_counts'])}, these operators have "
                            f"{mesh.vertex_counts}")
    if mesh.fingerprint() != trained["fingerprint"]:
        raise PipelineError(f"{operators_path}: same vertex counts but different operator tables than the ones "
                            f"the model in {path} was trained with for garment '{garment}'")


def save_garment_view(path: str | os.PathLike, model: MultiMeshRegressor, garment: str, spec: NetworkSpec,
                      mesh: MeshHierarchy, training: Mapping[str, Any]) -> None:
    """Garment `garment`'s regressor (the shared weights and normalisation, its mesh constants) as a model.pt of
    pipeline.train's format, recording the operators it runs on and, under `multi`, the garments whose shared
    network it is."""
    part = model.part(garment)
    save_model(Path(path), part, spec, mesh, {"training": dict(training),
                                              "multi": {"garment": garment, "garments": list(model.names)}})
