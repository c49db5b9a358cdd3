"""Stage `export_model`: a trained model as a self-contained upsampler that runs without the project's code.

    python -m pipeline.export_model MODEL.pt OPERATORS.h5 SUBDIV.h5 OUT_DIR [--settings SETTINGS.json]
        [--frame-time SECONDS] [--device cpu] [--quiet]

OUT_DIR receives upsampler.pt2 (torch.export: Loop subdivision, input features, the network with its index
tables), upsampler.json (the program's inputs), low_faces.npy, high_faces.npy and runner.py, which upsamples OBJ
or .npy frames with torch and numpy alone (deploy/README.md; docs/artifacts.md lists the files). The export is
checked against the eager network before anything is written. --frame-time (default with --settings: the
scene's `solver.dt`) is recorded as the default frame time of a model that sees velocities. On a CUDA --device
(default with --settings: the scene's `device`) OUT_DIR also receives upsampler_fused_cuda.pt2, the program of the
same path with the fused bf16 network, and kernels/, the package of its Triton operators (deploy/README.md),
checked the same way.
"""
from __future__ import annotations

import argparse
import hashlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm import tqdm

from deploy.export import EXPORT_FILES, export_upsampler
from pipeline.artifacts.model import load_model
from pipeline.artifacts.subdiv import read_subdivision
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write


def flags_from_settings(settings: dict) -> dict[str, Any]:
    return {"frame_time": settings["solver"]["dt"], "device": settings["device"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.export_model", description=__doc__.splitlines()[0])
    for name in ("model", "operators", "subdiv"):
        parser.add_argument(name)
    parser.add_argument("out_dir", help="folder to write the exported upsampler into")
    parser.add_argument("--frame-time", type=float, help="seconds between the training frames")
    parser.add_argument("--device", default="cpu", help="cuda: also the fused bf16 package, compiled for this GPU")
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    if args.frame_time is not None and not args.frame_time > 0:
        raise PipelineError(f"--frame-time must be > 0, got {args.frame_time}")
    cli.check_device(args.device, "torch", torch.cuda.device_count)
    cli.refuse_aliases({name: Path(args.out_dir) / name for name in EXPORT_FILES},
                       {"model": args.model, "operators": args.operators, "subdiv": args.subdiv})
    steps = tqdm(total=2, desc="export", unit="step", disable=args.quiet)
    model, mesh, state = load_model(args.model, args.operators, "cpu")
    subdivision = read_subdivision(args.subdiv)
    if not np.array_equal(subdivision.faces, model.features.faces.numpy()):
        raise PipelineError(f"{args.subdiv}: its high-res mesh is not the one the model in {args.model} was "
                            f"trained on")
    provenance = {"model": str(args.model), "model_sha256": hashlib.sha256(Path(args.model).read_bytes()).hexdigest(),
                  "arch_expanded": state["arch_expanded"], "network": state["spec"],
                  "parameter_count": state["parameter_count"],
                  "operators_fingerprint": state["operators"]["fingerprint"]}
    try:
        files = export_upsampler(model, mesh, subdivision.S, subdivision.faces, args.frame_time, provenance,
                                 fused_device=args.device if args.device.startswith("cuda") else None)
    except ValueError as err:
        raise PipelineError(f"{args.model}: cannot export ({err})") from None
    steps.update()
    for name, contents in files.items():
        with atomic_write(Path(args.out_dir) / name) as f:
            f.write(contents)
    steps.update()
    steps.close()


if __name__ == "__main__":
    cli.run(main)
