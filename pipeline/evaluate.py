"""Stage `evaluate`: errors, timing, pictures and exported meshes of a trained upsampling network.

    python -m pipeline.evaluate DATASET.h5 OPERATORS.h5 MODEL.pt EVAL.h5 REPORT.md [--settings SETTINGS.json]
        [--renders DIR] [--export DIR] [--render-frames 3] [--export-frames 60] [--timing-frames 30]
        [--device cpu] [--threads N] [--scene SCENE.h5] [--quiet]

Errors are those of paper Table 3 (L1 eq. 4 and L2 eq. 5, reported x 1e-3 scene units) on the train and test
frames, for the network and for its predictor alone (Loop subdivision, no network), so the network's gain shows.
Renders (default: `renders/` beside REPORT.md) put low-res input | ground truth | network output | error maps
side by side; the export folder (default `export/`) holds the predicted sequence as OBJ files and a GLB scene
comparing input, truth and prediction. With --scene of a garment scene, renders show the mannequin too.
docs/artifacts.md lists eval.h5's datasets. With --settings (a scene's resolved settings.json), `evaluation.*` and
`device` are the defaults of the flags of the same names.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm import tqdm

from geometry.rigid import apply_rigid_inverse
from model.losses import LossWeights
from model.training import split_errors
from pipeline import cli
from pipeline.artifacts.dataset import load_dataset, read_low_res
from pipeline.artifacts.evaluation import Evaluation, write_evaluation
from pipeline.artifacts.h5 import atomic_write
from pipeline.artifacts.model import load_model
from pipeline.artifacts.scene import read_body, read_torso_transforms
from pipeline.errors import PipelineError
from pipeline.torch_setup import configure_torch, frames_on
from scenes.body_mesh import body_mesh
from viz.export import write_glb, write_obj_sequence
from viz.render import Panel, render_panels, value_colors

PAPER_UNIT = 1e-3          # Table 3: "error should be multiplied by 10^-3"
WARMUP_RUNS = 3


def infer_all(model, mesh, inputs: torch.Tensor, batch_size: int = 8) -> torch.Tensor:
    """Predicted displacements of every frame."""
    with torch.no_grad():
        return torch.cat([model(inputs[i:i + batch_size], mesh) for i in range(0, len(inputs), batch_size)])


def time_inference(model, mesh, inputs: torch.Tensor) -> np.ndarray:
    """Milliseconds per frame (batch of one) for each of `inputs`, after warm-up runs; synchronised on CUDA."""
    sync = torch.cuda.synchronize if inputs.is_cuda else (lambda: None)
    times = []
    with torch.no_grad():
        for i in range(-WARMUP_RUNS, len(inputs)):
            frame = inputs[max(i, 0):max(i, 0) + 1]
            sync()
            start = time.perf_counter()
            model(frame, mesh)
            sync()
            if i >= 0:
                times.append((time.perf_counter() - start) * 1e3)
    return np.asarray(times)


def per_frame_errors(displacement_error: np.ndarray) -> dict[str, np.ndarray]:
    """L1 and L2 of each frame from (F, V, 3) position errors."""
    return {"l1": np.abs(displacement_error).mean(axis=(1, 2)),
            "l2": np.sqrt(np.square(displacement_error).sum(axis=2).mean(axis=1))}


def pick_frames(frames: np.ndarray, count: int) -> np.ndarray:
    """`count` frames spread evenly over `frames` (sorted ids)."""
    if count <= 0:
        return frames[:0]
    return frames[np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int))]


def body_meshes(scene_path: str | None, frames: np.ndarray, frame_name: str, n_frames: int) -> list | None:
    """The mannequin's mesh at each of `frames` (of `n_frames`) in the dataset's reference frame, or None for a
    scene without one (or no --scene)."""
    body = None if scene_path is None else read_body(scene_path)
    if body is None:
        return None
    skel, state = body
    rotation, translation = state.rotation[frames], state.translation[frames]
    torso = read_torso_transforms(scene_path, n_frames)[frames] if frame_name == "torso" else None
    # Drawn a little inside its collision surface and finely cut: matplotlib sorts whole faces by depth, and
    # large body faces a few mm under the cloth would otherwise poke through it.
    inset = 0.01 * skel.height / 1.7
    skel = dataclasses.replace(skel, radius_a=skel.radius_a - inset, radius_b=skel.radius_b - inset)
    meshes = []
    for i in range(len(frames)):
        vertices, faces = body_mesh(skel, (rotation[i], translation[i]), segments=32)
        if torso is not None:
            vertices = apply_rigid_inverse(torso[i], vertices)
        meshes.append((vertices, faces))
    return meshes


def render_frame(path: Path, frame: int, low: np.ndarray, low_faces: np.ndarray, predictor: np.ndarray,
                 truth: np.ndarray, predicted: np.ndarray, faces: np.ndarray, body=None, split: str = "test") -> Path:
    """Low-res input | ground truth | network output (on the body, if any) | |error| of the predictor (Loop
    subdivision alone) and of the network, on one colour scale."""
    predictor_error = np.linalg.norm(truth - predictor, axis=1)
    network_error = np.linalg.norm(truth - predicted, axis=1)
    panels = [Panel("low-res input", low, low_faces, backdrop=body),
              Panel("high-res ground truth", truth, faces, backdrop=body),
              Panel("network output", predicted, faces, backdrop=body),
              Panel("error: Loop subdivision", truth, faces, predictor_error),
              Panel("error: network", predicted, faces, network_error)]
    # A few boundary vertices can carry errors far above the rest: saturate them so the pattern shows.
    vmax = float(max(np.percentile(predictor_error, 99), np.percentile(network_error, 99)))
    return render_panels(path, panels, vmax=vmax, title=f"{split} frame {frame}",
                         value_label="|error| (scene units, clipped at 99th pct.)")


def flags_from_settings(settings: dict) -> dict[str, Any]:
    evaluation = settings["evaluation"]
    return {"render_frames": evaluation["render_frames"], "export_frames": evaluation["export_frames"],
            "timing_frames": evaluation["timing_frames"], "device": settings["device"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.evaluate", description=__doc__.splitlines()[0])
    for name in ("dataset", "operators", "model"):
        parser.add_argument(name)
    parser.add_argument("eval", help="eval.h5 to write"), parser.add_argument("report", help="report.md to write")
    parser.add_argument("--renders", help="folder of PNG renders (default: renders/ beside the report)")
    parser.add_argument("--export", help="folder of OBJ/GLB exports (default: export/ beside the report)")
    parser.add_argument("--render-frames", type=int, default=3, help="test frames to render")
    parser.add_argument("--export-frames", type=int, default=60, help="first frames exported as OBJ (0: all)")
    parser.add_argument("--timing-frames", type=int, default=30, help="test frames timed one by one")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--scene", help="scene.h5: draws the mannequin in the renders of a garment scene")
    cli.add_threads(parser)
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    if args.timing_frames < 1 or args.render_frames < 0:
        raise PipelineError("--timing-frames must be >= 1 and --render-frames >= 0")
    report_dir = Path(args.report).parent
    renders_dir = Path(args.renders) if args.renders else report_dir / "renders"
    export_dir = Path(args.export) if args.export else report_dir / "export"
    device = configure_torch(args.device, 0, args.threads)
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu, {torch.get_num_threads()} threads"
    data = load_dataset(args.dataset)
    model, mesh, state = load_model(args.model, args.operators, str(device))
    if mesh.vertex_counts[0] != data.inputs.shape[1]:
        raise PipelineError(f"{args.dataset}: {data.inputs.shape[1]} vertices, but the model's mesh has "
                            f"{mesh.vertex_counts[0]}")
    low_positions, low_faces = read_low_res(args.dataset)
    steps = tqdm(total=4, desc="evaluate", unit="step", disable=args.quiet)
    frames = frames_on(data, device)
    weights = LossWeights(**state["training"]["loss_weights"])
    predict = {"network": lambda x: model(x, mesh), "predictor": torch.zeros_like}
    errors = {who: {split: split_errors(fn, frames, torch.as_tensor(ids, device=device), 8, weights)
                    for split, ids in data.splits().items()}
              for who, fn in predict.items()}
    displacement = infer_all(model, mesh, frames.inputs).cpu().numpy()
    steps.update()
    timed = pick_frames(data.test, args.timing_frames)
    times = time_inference(model, mesh, frames.inputs[torch.as_tensor(timed, device=device)])
    steps.update()
    truth = data.inputs + data.targets
    predicted = data.inputs + displacement
    network_frame = per_frame_errors(displacement - data.targets)
    predictor_frame = per_frame_errors(-data.targets)
    # With an unseen motion, half the pictures show it.
    n_held = args.render_frames // 2 if len(data.held_out) else 0
    rendered = np.concatenate([pick_frames(data.test, args.render_frames - n_held), pick_frames(data.held_out, n_held)])
    bodies = body_meshes(args.scene, rendered, data.frame, len(data.inputs)) or [None] * len(rendered)
    pictures = [render_frame(renders_dir / f"frame_{frame:04d}.png", frame, low_positions[frame], low_faces,
                             data.inputs[frame], truth[frame], predicted[frame], data.faces, body,
                             "held-out" if frame in data.held_out else "test")
                for frame, body in zip(rendered, bodies)]
    steps.update()
    n_export = len(predicted) if args.export_frames <= 0 else min(args.export_frames, len(predicted))
    write_obj_sequence(export_dir / "predicted_obj", predicted[:n_export], data.faces, range(n_export))
    if len(rendered):
        frame = rendered[0]
        error = np.linalg.norm(predicted[frame] - truth[frame], axis=1)
        write_glb(export_dir / f"comparison_frame_{frame:04d}.glb",
                  [("low_res_input", low_positions[frame], low_faces, None),
                   ("ground_truth", truth[frame], data.faces, None),
                   ("network_output", predicted[frame], data.faces, value_colors(error, float(error.max())))])
    config = {**{k: v for k, v in vars(args).items() if k != "quiet"}, "model_spec": state["spec"]}
    write_evaluation(args.eval, config, Evaluation(errors, {"network": network_frame, "predictor": predictor_frame},
                                                   predicted, times, timed, where, WARMUP_RUNS,
                                                   state["parameter_count"]))
    _write_report(Path(args.report), args, errors, times, where, state, data, pictures, export_dir, n_export,
                  low_positions.shape[1])
    steps.update()
    steps.close()


def _write_report(path: Path, args, errors, times, device, state, data, pictures, export_dir, n_export,
                  n_low) -> None:
    spec, training = state["spec"], state["training"]
    rel = lambda p: os.path.relpath(p, path.parent)  # noqa: E731
    scaled = lambda who, split, term: errors[who][split][term] / PAPER_UNIT  # noqa: E731
    splits = list(data.splits())
    rows = []
    for who, label in (("network", "network"), ("predictor", "Loop subdivision alone (predictor)")):
        cells = [f"{scaled(who, s, t):.3f}" for s in splits for t in ("l1", "l2")]
        rows.append(f"| {label} | " + " | ".join(cells) + f" | {errors[who]['test']['normal']:.4f} |")
    gains = [scaled("predictor", s, t) / max(scaled("network", s, t), 1e-30) for s in splits for t in ("l1", "l2")]
    rows.append("| gain (predictor / network) | " + " | ".join(f"{g:.2f}x" for g in gains) + " | |")
    header = "| | " + " | ".join(f"{s.replace('_', '-')} {t}" for s in splits for t in ("L1", "L2")) + " | test Ln |"
    held_note = ([f"Held-out: every frame of the motion clip(s) `{data.held_out_clips}`, never seen in training (the "
                  "generalisation test); test: a random share of the frames of the trained motions.", ""]
                 if "held_out" in splits else [])
    lines = [
        f"# Evaluation of `{args.model}`", "",
        f"- Network: {state['arch_expanded']} (encoder-decoder), conv {spec['conv']}, {spec['pool']} pooling, "
        f"width {spec['width']:g}: **{state['parameter_count']:,} learnable parameters**.",
        f"- Training: {training['epochs']} epochs on {training['device']}, batch size {training['batch_size']}, "
        f"Adam lr {training['lr']:g}, seed {training['seed']}, loss weights "
        f"L1 {training['loss_weights']['l1']:g} / L2 {training['loss_weights']['l2']:g} / "
        f"Ln {training['loss_weights']['normal']:g}.",
        f"- Data: `{args.dataset}`, {len(data.inputs)} frames ("
        + ", ".join(f"{len(ids)} {name.replace('_', '-')}" for name, ids in data.splits().items()) + "), "
        f"{n_low} low-res -> {data.inputs.shape[1]} high-res vertices, positions in the {data.frame} frame.", "",
        "## Errors (x 1e-3 scene units, as paper Table 3)", "",
        header, "|---" * (2 * len(splits) + 2) + "|", *rows, "", *held_note,
        "L1 = mean over vertices of |x_truth - x|_1 / 3 (eq. 4); L2 = sqrt(mean over vertices of "
        "|x_truth - x|^2) (eq. 5), both over all frames of a split; Ln = face-normal L1 (eq. 6, dimensionless).",
        "", "## Inference time", "",
        f"Median **{np.median(times):.2f} ms per frame** on {device} (network only, one frame per call, "
        f"{len(times)} test frame(s) timed after {WARMUP_RUNS} warm-up runs; min {times.min():.2f}, "
        f"max {times.max():.2f} ms). Paper Table 3 (RTX 2080 Ti, C++/cuBLAS, including GPU Loop subdivision): "
        "2.2-26.6 ms for 4k-15k vertices.", "", "## Renders", "",
        "Test (and held-out) frames: low-res input | high-res ground truth | network output | |error| of Loop subdivision "
        "alone | |error| of the network (one colour scale, saturating at the 99th percentile of either).", "",
        *[f"![{p.stem}]({rel(p)})" for p in pictures], "", "## Files", "",
        f"- `{rel(Path(args.eval))}`: errors, per-frame errors, predicted positions, inference times.",
        f"- `{rel(export_dir / 'predicted_obj')}/`: predicted positions of frames 0-{n_export - 1} as OBJ.",
    ]
    if pictures:
        lines.append(f"- `{rel(export_dir)}/comparison_frame_*.glb`: input, truth and error-coloured prediction "
                     "side by side (any glTF viewer).")
    with atomic_write(path) as f:
        f.write(("\n".join(lines) + "\n").encode())


if __name__ == "__main__":
    cli.run(main)
