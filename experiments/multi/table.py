"""results/multi/multi.h5, written by `experiments.multi.report`: per garment the errors of Loop subdivision alone,
of the garment's own network and of the network shared by every garment, their size and inference time
(docs/artifacts.md, section "multi/multi.h5")."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, open_artifact, read

STAGE = "multi_report"
WHO = ("predictor", "own", "shared")       # Loop subdivision alone; the garment's own network; the shared one
NETWORKS = ("own", "shared")
TERMS = ("l1", "l2")


@dataclasses.dataclass(frozen=True)
class MultiTable:
    """One entry per garment (in `garments` order) of every array."""

    garments: list[str]
    vertices: np.ndarray                                   # (G,) high-res vertices of each garment
    splits: list[str]                                      # the splits every garment has (train, test, held_out)
    errors: dict[str, dict[str, dict[str, np.ndarray]]]    # who -> split -> term -> (G,) scene units
    inference_ms: dict[str, np.ndarray]                    # own/shared -> (G,) median ms per frame
    parameters: int                                        # learnable parameters of each network (the same size)
    network: str                                           # "<conv> x<width>"
    device: str                                            # where the networks were timed, in words


def write_multi_table(path: str | os.PathLike, config: Mapping[str, Any], table: MultiTable) -> None:
    with atomic_h5(path, STAGE, config) as f:
        f.create_dataset("garments", data=np.array(table.garments, dtype="S"))
        f.create_dataset("vertices", data=np.asarray(table.vertices, dtype=np.int64))
        for who in WHO:
            for split in table.splits:
                for term in TERMS:
                    f.create_dataset(f"errors/{who}/{split}/{term}",
                                     data=np.asarray(table.errors[who][split][term], dtype=np.float64))
        f["errors"].attrs.update(
            meaning="split-wide L1 (eq. 4) and L2 (eq. 5) per garment: predictor = Loop subdivision alone, own = the "
                    "garment's own network (results/<scene>/eval.h5), shared = the network trained on every garment "
                    "(results/multi/<scene>/eval.h5)", unit="scene units (~m)")
        for who in NETWORKS:
            f.create_dataset(f"inference_ms/{who}", data=np.asarray(table.inference_ms[who], dtype=np.float64))
        f["inference_ms"].attrs["meaning"] = "median ms per frame on the deployment path (eval.h5 inference_ms)"
        f.attrs.update(parameters=table.parameters, network=table.network, device=table.device)


def read_multi_table(path: str | os.PathLike) -> MultiTable:
    with open_artifact(path) as f:
        garments = [name.decode() for name in read(f, "garments")]
        splits = [s for s in ("train", "test", "held_out") if f"errors/predictor/{s}" in f]
        errors = {who: {split: {term: read(f, f"errors/{who}/{split}/{term}", np.float64) for term in TERMS}
                        for split in splits} for who in WHO}
        table = MultiTable(garments, read(f, "vertices", np.int64), splits, errors,
                           {who: read(f, f"inference_ms/{who}", np.float64) for who in NETWORKS},
                           int(f.attrs["parameters"]), str(f.attrs["network"]), str(f.attrs["device"]))
    arrays = [table.vertices, *table.inference_ms.values(),
              *(a for splits in errors.values() for terms in splits.values() for a in terms.values())]
    if not splits or any(np.shape(a) != (len(garments),) for a in arrays):
        raise PipelineError(f"{path}: every array must hold one value per garment ({len(garments)})")
    return table
