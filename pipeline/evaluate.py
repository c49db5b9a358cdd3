"""Stage `evaluate`: errors, timing, pictures, videos, reports and exported meshes of a trained network of any task.

    python -m pipeline.evaluate DATASET.h5 OPERATORS.h5 MODEL.pt EVAL.h5 REPORT.md [--settings SETTINGS.json]
        [--html REPORT.html] [--train-log TRAIN.h5] [--scene SCENE.h5] [--renders DIR] [--videos DIR]
        [--export DIR] [--render-frames 3] [--video-frames 120] [--export-frames 60] [--timing-frames 30]
        [--no-fused-timing] [--device cpu] [--device-cache-gb GB] [--threads N] [--quiet]

Errors are those of paper Table 3 (L1 eq. 4 and L2 eq. 5, reported x 1e-3 scene units) on the train and test
frames, for the network and for its predictor alone (no network), so the network's gain shows. The dataset's task
(pipeline/tasks) says what the predictor is: Loop subdivision (upsampling), linear blend skinning (pose), the PCA
reconstruction (pca); for a decoder task the first panel of a picture is the predictor instead of the low-res run.
Pictures (default: `renders/` beside REPORT.md): stills of test and held-out frames, low-res input | ground truth
| network output | error maps, and plots of the per-frame error over time and, with --train-log, of the training
curve. Videos (default: `videos/`): the held-out motion and a stretch of a training sequence around its test
frames, low-res input | ground truth | network output | error, in real time (MP4, or GIF without an encoder).
Every still and video frame goes through one camera, fitted to the garment of all frames shown, and one error
colour scale. With --scene (a scene.h5, or dataset.h5, which carries each frame's mannequin) the body is drawn.
The export folder (default `export/`) holds the predicted sequence as OBJ files and a GLB scene comparing input,
truth and prediction. A dataset of motion-library windows adds the held-out and test errors per category of the
library's manifest and per subject, and a dataset that lists sequences dropped on the way adds them with their
reasons. report.md links all of it; --html writes one self-contained page that embeds it.
The network runs over every frame a chunk at a time (model.scoring), each chunk reduced to its frames' errors on
the device: only the frames shown (stills, videos, GLB) are held to the end; eval.h5's predicted positions and the
OBJ files are written as the chunks come. The frames stay on the device as training keeps them (within
--device-cache-gb, default half the free memory); a larger dataset is read from disk a chunk at a time, with the
same arithmetic (model.streaming). A network that reads its own previous output is rolled out over every frame at
once, from a resident dataset only.
A failed run leaves nothing behind: folders are filled under temporary names beside their final ones and renamed
at the end, every file is written atomically. docs/artifacts.md lists what is written. With --settings (a
scene's resolved settings.json), `evaluation.*`, `training.device_cache_gb` and `device` are the defaults of the
flags of the same names.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import secrets
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import torch
from tqdm import tqdm

from geometry.rigid import apply_rigid_inverse
from model.losses import LossWeights
from model.scoring import Predict, score_frames
from model.training import Frames
from model.training_step import LR_SCHEDULES
from pipeline.artifacts.dataset import (WINDOWS, FrameReader, LearningData, LibraryWindows, load_dataset,
                                        read_dropped, read_library_windows)
from pipeline.artifacts.evaluation import GROUPINGS, TERMS, WHO, Evaluation, GroupErrors, evaluation_output
from pipeline.artifacts.model import load_model
from pipeline.artifacts.scene import read_body, read_torso_transforms
from pipeline.artifacts.train_log import TrainLog, read_train_log
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write, check_same_mesh, write_bytes
from pipeline.core.torch_setup import configure_torch, timing_device
from pipeline.tasks import streams_frames, task_of
from pipeline.tasks.scoring import FrameOutputs, evaluation_frames, network_predict
from pipeline.tasks.task import HostFrames, Task
from pipeline.tasks.timing import WARMUP_RUNS, pick_frames
from scenes.body_mesh import body_mesh
from viz.animation import encode_animation
from viz.comparison import Comparison, FrameMeshes, comparison_image, fit_comparison
from viz.export import glb_bytes, obj_bytes
from viz.html_report import Links, Paragraphs, Picture, Section, Table, Video, report_html
from viz.markdown_report import report_markdown
from viz.plots import error_over_time, figure_bytes, training_curve
from viz.render import png_bytes, value_colors

PAPER_UNIT = 1e-3          # Table 3: "error should be multiplied by 10^-3"
VIDEO_PANEL_HEIGHT = 3.6   # inches at 100 dpi; stills are 4.5 and supersampled, video frames are not (speed)
SPLIT_NAMES = {"train": "train", "test": "test", "held_out": "held-out"}
# The group of the frames of sequences that play no motion-library window (motion programs, the settings' test
# clips), and of windows whose manifest gives no category, in the errors by motion kind.
NO_WINDOW, NO_CATEGORY = "(no library window)", "(no category)"


def errors_by_kind(per_frame: dict[str, dict[str, np.ndarray]], sequence: np.ndarray, windows: LibraryWindows,
                   splits: dict[str, np.ndarray]) -> dict[str, GroupErrors]:
    """The errors of each split of `splits` over the frames of each manifest category and of each subject, from
    the per-frame errors (who -> l1/l2 -> (F,)) and each frame's sequence: a group's L1 is the mean of its frames'
    (every frame has the same vertices), its L2 the root of the mean of their squares, as a split's are."""
    labels_of = {"category": [(c or NO_CATEGORY) if f else NO_WINDOW for f, c in zip(windows.file, windows.category)],
                 "subject": [s if f else NO_WINDOW for f, s in zip(windows.file, windows.subject)]}
    by_kind = {}
    for grouping in GROUPINGS:
        per_sequence = labels_of[grouping]
        labels = sorted(set(per_sequence), key=_group_order)
        group = np.array([labels.index(label) for label in per_sequence], dtype=np.int64)[sequence]
        frames, errors = {}, {}
        for split, ids in splits.items():
            frames[split] = np.bincount(group[ids], minlength=len(labels))
            errors[split] = {who: {"l1": _group_mean(group[ids], per_frame[who]["l1"][ids], frames[split]),
                                   "l2": np.sqrt(_group_mean(group[ids], per_frame[who]["l2"][ids] ** 2,
                                                             frames[split]))} for who in WHO}
        by_kind[grouping] = GroupErrors(tuple(labels), frames, errors)
    return by_kind


def _group_mean(group: np.ndarray, values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The mean of `values` per group (`group` of each value; `counts` values in each): NaN for an empty group."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.bincount(group, values, len(counts)) / counts


def _group_order(label: str) -> tuple:
    """Groups in order: by number where a label is one (subjects 2, 10, 16), else by name; the frames of no
    library window last."""
    return (label == NO_WINDOW, not label.isdigit(), int(label) if label.isdigit() else 0, label)


def stretch_around_test_frames(data: LearningData, count: int) -> np.ndarray:
    """`count` consecutive frames of one training sequence (all of it if shorter): the window holding the most
    test frames, the earliest of equals. Test frames alone are a random share, rarely consecutive, and motion is
    judged at its real speed. (A sequence's frames have consecutive ids in the dataset.)"""
    is_test = np.zeros(len(data.sequence))
    is_test[data.test] = 1.0
    best, most = data.test[:0], -1.0
    for sequence in np.unique(data.sequence[data.test]):
        frames = np.flatnonzero(data.sequence == sequence)
        n = min(count, len(frames))
        if n <= 0:
            break
        tests = np.convolve(is_test[frames], np.ones(n), "valid")
        start = int(np.argmax(tests))
        if tests[start] > most:
            best, most = frames[start:start + n], tests[start]
    return best


def body_meshes(scene_path: str | None, frames: np.ndarray, frame_name: str,
                n_frames: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The mannequin's mesh at each of `frames` (of `n_frames`) in the dataset's reference frame; none for a
    scene without one (or no --scene). Drawn at its collision surface: the renderer's z-buffer shows exactly what
    is in front, so body seen through the cloth is cloth inside the body."""
    body = None if scene_path is None or len(frames) == 0 else read_body(scene_path)
    if body is None:
        return {}
    skel, state = body
    torso = read_torso_transforms(scene_path, n_frames) if frame_name == "torso" else None
    meshes = {}
    for frame in frames:
        vertices, faces = body_mesh(skel, (state.rotation[frame], state.translation[frame]))
        if torso is not None:
            vertices = apply_rigid_inverse(torso[frame], vertices)
        meshes[int(frame)] = (vertices, faces)
    return meshes


@contextlib.contextmanager
def staged_folders(finals: Mapping[str, tuple[Path, bool]]) -> Iterator[dict[str, Path]]:
    """A new, empty temporary folder beside each final folder (role -> (path, keep even if empty)), renamed to
    it once the block succeeds (replacing a folder of that name left by an earlier run), and removed with all it
    holds if the block fails: a failed evaluation leaves no half-filled folder behind. A folder left empty is
    dropped unless kept: a flag naming a folder (a Snakemake directory output) always gets one."""
    staged: dict[str, Path] = {}
    try:
        for role, (final, _) in finals.items():
            final.parent.mkdir(parents=True, exist_ok=True)
            # A new folder of an unguessable name (os.mkdir fails on anything there, a planted link included),
            # with the mode the umask gives a folder (mkdtemp's would be 0700).
            staged[role] = final.parent / f".{final.name}.{secrets.token_hex(8)}"
            os.mkdir(staged[role])
        yield staged
        for role, (final, keep_empty) in finals.items():
            if keep_empty or any(staged[role].iterdir()):
                _replace_folder(staged[role], final)
    finally:
        for folder in staged.values():
            shutil.rmtree(folder, ignore_errors=True)


def _replace_folder(new: Path, final: Path) -> None:
    """Rename `new` to `final`; whatever `final` was (a folder, a file, a link) is moved aside first, then
    removed (os.replace cannot rename a folder onto a non-empty one)."""
    if not final.exists() and not final.is_symlink():
        os.replace(new, final)
        return
    trash = Path(tempfile.mkdtemp(prefix=f".{final.name}.old.", dir=final.parent))
    try:
        os.replace(final, trash / final.name)
        os.replace(new, final)
    finally:
        shutil.rmtree(trash, ignore_errors=True)


def video_clips(data: LearningData, count: int) -> list[tuple[str, np.ndarray, float, str]]:
    """(name, frames, frames per second, caption) of each video: the held-out motion, `count` of its frames
    spread evenly and played in real time, and a stretch of `count` consecutive frames of a training sequence
    around its test frames, at the scene's frame rate; none for `count` 0."""
    clips = []
    rate = 1.0 / data.context.frame_time
    held = pick_frames(data.held_out, count)
    if len(held):
        fps = rate * len(held) / len(data.held_out)
        clips.append(("held_out", held, fps,
                      f"Held-out motion ({data.held_out_clips}), never trained on: {len(held)} of its "
                      f"{len(data.held_out)} frames, evenly spaced, in real time ({fps:.3g} frames/s)."))
    stretch = stretch_around_test_frames(data, count)
    if len(stretch):
        n_test, n_guard = np.isin(stretch, data.test).sum(), np.isin(stretch, data.guard).sum()
        guard = f" and {n_guard} guard frames (in no split)" if n_guard else ""
        clips.append(("test", stretch, rate,
                      f"Frames {stretch[0]}-{stretch[-1]} of a training sequence, {n_test} of them test "
                      f"frames{guard} (the others trained on; each frame's title says which), at the scene's "
                      f"{rate:.3g} frames/s."))
    return clips


def flags_from_settings(settings: dict) -> dict[str, Any]:
    evaluation = settings["evaluation"]
    return {"render_frames": evaluation["render_frames"], "video_frames": evaluation["video_frames"],
            "export_frames": evaluation["export_frames"], "timing_frames": evaluation["timing_frames"],
            "device": settings["device"], "device_cache_gb": settings["training"]["device_cache_gb"],
            "garment": settings["mesh"]["file"] if settings["mesh"]["generator"] == "garment_file" else None,
            "hand_files": (f"{settings['mesh']['file']} and {settings['mesh']['bones']}"
                           if settings["mesh"]["generator"] == "hand_file" else None)}


def main(argv: Sequence[str] | None = None) -> None:
    started = time.perf_counter()
    parser = argparse.ArgumentParser(prog="python -m pipeline.evaluate", description=__doc__.splitlines()[0])
    for name in ("dataset", "operators", "model"):
        parser.add_argument(name)
    parser.add_argument("eval", help="eval.h5 to write"), parser.add_argument("report", help="report.md to write")
    parser.add_argument("--html", help="self-contained report.html to write (default: none)")
    parser.add_argument("--train-log", help="train.h5 of the model: its training curve goes in the reports")
    parser.add_argument("--scene", help="scene.h5 (or dataset.h5) of a garment scene: draws the mannequin")
    parser.add_argument("--renders", help="folder of stills and plots (default: renders/ beside the report)")
    parser.add_argument("--videos", help="folder of videos (default: videos/ beside the report)")
    parser.add_argument("--export", help="folder of OBJ/GLB exports (default: export/ beside the report)")
    parser.add_argument("--render-frames", type=int, default=3,
                        help="test (and held-out) frames shown as stills; 0: no stills and no plots")
    parser.add_argument("--garment", help="the user's garment file the scene wore, named in the report "
                                          "(--settings: mesh.file of a garment_file scene)")
    parser.add_argument("--hand-files", help="the user's hand skin and bone files, named in the report "
                                             "(--settings: mesh.file and mesh.bones of a hand_file scene)")
    parser.add_argument("--video-frames", type=int, default=120, help="frames of each video; 0: no videos")
    parser.add_argument("--export-frames", type=int, default=60, help="first frames exported as OBJ (0: all)")
    parser.add_argument("--tradeoff-report", help="the scene's tradeoff/report.md, listed under the report's "
                                                  "files (made by its own target; the link works once it exists)")
    parser.add_argument("--study-report", help="the scene's study/report.md, likewise")
    parser.add_argument("--convs-report", help="the scene's convs/report.md (the operator comparison), likewise")
    parser.add_argument("--timing-frames", type=int, default=30, help="test frames timed one by one")
    parser.add_argument("--no-fused-timing", action="store_true",
                        help="on CUDA, time the fp32 deployment path only, not the fused bf16 network beside it: "
                             "grids whose tables do not read the fused figure skip its compiling and autotuning "
                             "(8-60 s an evaluation on a shared GPU, docs/performance.md)")
    parser.add_argument("--no-predictions", action="store_true",
                        help="eval.h5 without every frame's predicted positions (errors and times only: a grid of "
                             "evaluations at the paper profile would otherwise store 1.8 GB each)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--device-cache-gb", type=float,
                        help="GiB of frames kept on the device, as training keeps them; a larger dataset is read from "
                             "disk a chunk at a time (default: half the free memory)")
    cli.add_threads(parser)
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    if args.timing_frames < 1 or args.render_frames < 0 or args.video_frames < 0:
        raise PipelineError("--timing-frames must be >= 1, --render-frames and --video-frames >= 0")
    if args.device_cache_gb is not None and not 0 <= args.device_cache_gb < math.inf:
        raise PipelineError("--device-cache-gb must be finite and >= 0")
    report_dir = Path(args.report).parent   # the folders' default home
    folders = {role: (Path(given) if given else report_dir / role, given is not None)
               for role, given in (("renders", args.renders), ("videos", args.videos), ("export", args.export))}
    cli.refuse_aliases({"eval.h5": args.eval, "report": args.report, **({"html": args.html} if args.html else {}),
                        **{f"--{role}": path for role, (path, _) in folders.items()}},
                       {"dataset": args.dataset, "operators": args.operators, "model": args.model,
                        "scene": args.scene, "train log": args.train_log})
    device = configure_torch(args.device, 0, args.threads)
    where = timing_device(device)
    stream, n_bytes = streams_frames(args.dataset, args.device_cache_gb, device)
    data = load_dataset(args.dataset, frames=not stream)
    check_same_mesh(args.operators, args.dataset)   # operators of a moved copy of the mesh have the same faces
    task = task_of(data.task, args.dataset)
    model, mesh, state = load_model(args.model, args.operators, str(device))
    task.check_model(state, args.model, args.dataset)
    if not task.trained_on(model, mesh, data):
        raise PipelineError(f"{args.dataset}: its mesh is not the one the model in {args.model} was trained on")
    if stream and not args.quiet:
        print(f"evaluate: {n_bytes / 2 ** 30:.2f} GiB of frames streamed from {args.dataset} (more than "
              f"--device-cache-gb or half the free memory)", file=sys.stderr)
    with contextlib.closing(FrameReader(args.dataset)) if stream else contextlib.nullcontext() as reader:
        frames = evaluation_frames(task, data, reader, device)
        predict = network_predict(model, mesh, frames, stream, n_bytes, args.dataset)
        _evaluate(args, folders, Evaluated(data, task, model, mesh, state, frames, predict,
                                           task.host_frames(data, args.dataset, reader), device, where, started))


@dataclasses.dataclass(frozen=True)
class Evaluated:
    """What an evaluation runs on: the dataset (its frames resident or streamed), the model and where it runs."""

    data: LearningData
    task: Task
    model: Any
    mesh: Any
    state: dict
    frames: Frames               # on the device: every frame, or a staging area filled from disk
    predict: Predict
    host: HostFrames             # the frames on the host, a run at a time
    device: torch.device
    where: str                   # the device in words
    started: float               # time.perf_counter() at the stage's start: its phases are timed from there


def _evaluate(args, folders: dict[str, tuple[Path, bool]], run: Evaluated) -> None:
    """Score every frame a chunk at a time (model.scoring), keeping the predictions of the frames shown and
    writing eval.h5's and the exports' as they come; then the pictures, videos and reports."""
    data, task, report_dir = run.data, run.task, Path(args.report).parent
    train_log = read_train_log(args.train_log) if args.train_log else None
    steps = tqdm(total=5, desc="evaluate", unit="step", disable=args.quiet)
    # Where the stage's time goes (eval.h5's phase_seconds): in grids of evaluations the loading and the timing
    # can outweigh the scoring.
    phases, mark = {"load": time.perf_counter() - run.started}, time.perf_counter()

    def phase(name: str) -> None:
        nonlocal mark
        phases[name], mark = time.perf_counter() - mark, time.perf_counter()

    weights = LossWeights(**run.state["training"]["loss_weights"])
    n_frames = len(data.sequence)
    # With an unseen motion, half the stills show it.
    n_held = args.render_frames // 2 if len(data.held_out) else 0
    stills = np.concatenate([pick_frames(data.test, args.render_frames - n_held), pick_frames(data.held_out, n_held)])
    clips = video_clips(data, args.video_frames)
    shown = np.unique(np.concatenate([stills, *(clip_frames for _, clip_frames, _, _ in clips)])).astype(np.int64)
    n_export = n_frames if args.export_frames <= 0 else min(args.export_frames, n_frames)
    config = {**{k: v for k, v in vars(args).items() if k != "quiet"}, "model_spec": run.state["spec"]}
    stored = None if args.no_predictions else (n_frames, len(data.rest_vertices), 3)
    with staged_folders(folders) as staged, evaluation_output(args.eval, config, stored) as out:
        objs = staged["export"] / "predicted_obj"
        outputs = FrameOutputs(run.host, shown, n_export, lambda frame, positions: write_bytes(
            objs / f"frame_{frame:04d}.obj", obj_bytes(positions, data.faces)), out.write_predicted if stored else None)
        scores = score_frames(run.predict, run.frames, n_frames, on_chunk=outputs)
        errors = {who: {split: scores.split(who, ids, weights) for split, ids in data.splits().items()}
                  for who in WHO}
        phase("score")
        steps.update()
        timed = pick_frames(data.test, args.timing_frames)
        times = task.time(run.model, run.mesh, run.frames.all_frames()[0], torch.as_tensor(timed, device=run.device),
                          fused=not args.no_fused_timing)
        phase("time")
        steps.update()
        per_frame = scores.per_frame
        windows = read_library_windows(args.dataset)
        by_kind = {} if windows is None else errors_by_kind(
            per_frame, data.sequence, windows, {name: ids for name, ids in data.splits().items() if name != "train"})
        bodies = body_meshes(args.scene, shown, data.frame, n_frames)
        kept = [outputs.meshes[frame] for frame in shown]
        comparison = None if len(shown) == 0 else fit_comparison(
            [np.stack([m.low for m in kept])], [np.stack([m.truth for m in kept])], run.host.input_faces,
            data.faces, [np.stack([np.linalg.norm(m.truth - getattr(m, who), axis=1) for m in kept])
                         for who in ("predictor", "predicted")],
            input_label=task.input_label, predictor_label=task.predictor_label, truth_label=task.truth_label)

        def frame_meshes(frame: int) -> FrameMeshes:
            return dataclasses.replace(outputs.meshes[int(frame)], body=bodies.get(int(frame)))

        def frame_title(frame: int) -> str:
            split = next((SPLIT_NAMES[name] for name, ids in data.splits().items() if frame in ids), "guard")
            return f"{split} frame {frame}"

        pictures = []
        for frame in stills:
            image = comparison_image(comparison, frame_meshes(frame), frame_title(frame))
            pictures.append(staged["renders"] / f"frame_{frame:04d}.png")
            write_bytes(pictures[-1], png_bytes(image))
        plots = _write_plots(staged["renders"], per_frame, data, train_log, task) if args.render_frames else {}
        phase("pictures")
        steps.update()
        videos = [(_write_video(staged["videos"] / name, comparison, clip_frames, fps, frame_meshes, frame_title),
                   caption) for name, clip_frames, fps, caption in clips]
        phase("videos")
        steps.update()
        exports = _write_exports(staged["export"], n_export, stills[:1], frame_meshes, run.host.input_faces,
                                 data.faces, task)

        def final(path: Path) -> Path:
            role = next(role for role, folder in staged.items() if path.is_relative_to(folder))
            return folders[role][0] / path.relative_to(staged[role])

        def href(path: Path) -> str:
            return os.path.relpath(final(path), report_dir)

        files = [(label, href(path)) for label, path in exports] + [
            ("eval.h5: errors, per-frame errors, " + ("" if args.no_predictions else "predicted positions, ")
             + "inference times", os.path.relpath(args.eval, report_dir))] + [
            (label, os.path.relpath(path, report_dir)) for label, path in (
                ("the speed-accuracy trade (target results/<scene>/tradeoff/)", args.tradeoff_report),
                ("the generalisation study (target results/<scene>/study/)", args.study_report),
                ("the operator comparison, RC, EC, SP and SPD (target results/<scene>/convs/)", args.convs_report))
            if path]
        sections = _report_sections(args, run.state, data, errors, times, run.where, run.host.input_vertices,
                                    train_log, pictures, plots, videos, files, task,
                                    _motion_kind_sections(by_kind, read_dropped(args.dataset), task))
        title = f"Evaluation of {args.model}"
        markdown = report_markdown(title, sections, href).encode()
        page = report_html(title, sections).encode() if args.html else None
        phase("exports and report")
        out.finish(Evaluation(errors, per_frame, None, times, timed, run.where, WARMUP_RUNS,
                              run.state["parameter_count"], trained_frame_count(run.state["training"], data), by_kind,
                              times.fused, task.predictor_label, phases))
        with atomic_write(args.report) as f:
            f.write(markdown)
        if page is not None:
            with atomic_write(args.html) as f:
                f.write(page)
    steps.update()
    steps.close()


def _write_video(stem: Path, comparison: Comparison, frames: np.ndarray, fps: float,
                 frame_meshes: Callable[[int], FrameMeshes], frame_title: Callable[[int], str]) -> Path:
    """The frames' comparisons (the network's error only) as `stem`.mp4, or .gif without an encoder; each frame
    is rendered as the encoder asks for it."""
    animation = encode_animation((comparison_image(comparison, frame_meshes(frame), frame_title(frame),
                                                   predictor_error=False, panel_height=VIDEO_PANEL_HEIGHT,
                                                   supersample=1) for frame in frames), fps)
    path = stem.with_suffix(animation.suffix)
    write_bytes(path, animation.data)
    return path


def _write_exports(folder: Path, n_export: int, glb_frames: np.ndarray,
                   frame_meshes: Callable[[int], FrameMeshes], low_faces: np.ndarray, faces: np.ndarray,
                   task: Task) -> list[tuple[str, Path]]:
    """Each of `glb_frames` as a GLB comparison beside the first `n_export` predicted frames' OBJ files (written
    as the frames were scored: FrameOutputs); (label, path) of each."""
    exports = [(f"predicted_obj/: predicted positions of frames 0-{n_export - 1} as OBJ", folder / "predicted_obj")]
    for frame in glb_frames:
        meshes = frame_meshes(frame)
        error = np.linalg.norm(meshes.predicted - meshes.truth, axis=1)
        path = folder / f"comparison_frame_{frame:04d}.glb"
        write_bytes(path, glb_bytes(
            [(task.input_label.replace(" ", "_").replace("-", "_"), meshes.low, low_faces, None),
             ("ground_truth", meshes.truth, faces, None),
             ("network_output", meshes.predicted, faces, value_colors(error, float(error.max())))]))
        exports.append((f"{path.name}: input, truth and error-coloured prediction side by side (any glTF viewer)",
                        path))
    return exports


def _write_plots(folder: Path, per_frame: dict, data: LearningData, train_log: TrainLog | None,
                 task: Task) -> dict[str, Path]:
    """The per-frame L1 of the network and of its predictor alone over the test and held-out frames, and the
    training curve (with a train log), as PNGs in `folder`; by name."""
    starts = np.flatnonzero(np.diff(data.sequence, prepend=-1) != 0)
    held_clips = iter(data.held_out_clips.split(","))
    labels = [next(held_clips, "held out") if np.isin(start, data.held_out) else f"seq {k}"
              for k, start in enumerate(starts)]
    figures = {"error_over_time": error_over_time(
        per_frame["network"]["l1"] / PAPER_UNIT, per_frame["predictor"]["l1"] / PAPER_UNIT,
        {name: ids for name, ids in data.splits().items() if name != "train"},
        list(zip(starts.tolist(), labels)), error_label="L1 (x 1e-3 scene units)",
        title=f"Per-frame error: network and {task.predictor_label} alone",
        predictor_label=f"{task.predictor_label} alone")}
    if train_log is not None:
        figures["training_curve"] = training_curve(train_log.train_total, train_log.test_total,
                                                   title="Training curve (loss = eq. 7, weighted total)")
    paths = {}
    for name, figure in figures.items():
        paths[name] = folder / f"{name}.png"
        write_bytes(paths[name], figure_bytes(figure, "png", dpi=100))
    return paths


def _training_option_rows(training: dict) -> list[list[str]]:
    """Report rows for the training options a model.pt records (older ones record none): each shown only when it
    holds a value of its kind, since the file may come from anywhere."""
    rows = []
    if training.get("lr_schedule") in LR_SCHEDULES:
        rows.append(["learning-rate schedule", "cosine down to 1 %" if training["lr_schedule"] == "cosine"
                     else "constant"])
    noise = training.get("input_noise")
    if isinstance(noise, (int, float)) and not isinstance(noise, bool) and math.isfinite(noise):
        rows.append(["input noise (std, normalised units)", f"{noise:g}" if noise else "none"])
    flags = [training.get(key) for key in ("cuda_graph", "deterministic", "tf32")]
    if all(isinstance(flag, bool) for flag in flags):
        graph, deterministic, tf32 = flags
        rows.append(["optimiser step", ", ".join([
            "one CUDA graph" if graph else "eager",
            "deterministic" if deterministic else "atomic adds (not bit-reproducible)",
            "TF32 products" if tf32 else "float32 products"])])
    sampling = training.get("sampling")
    if isinstance(sampling, dict) and isinstance(sampling.get("share"), (int, float)):
        rows.append(["frames per epoch", "every training frame" if sampling["share"] >= 1 else
                     f"a share of {sampling['share']:g}, in blocks of {sampling.get('block')} frames"])
    if trained_on_held_out(training):
        rows.append(["splits trained on", "train and held-out: an oracle (see the errors)"])
    sequences = training.get("sequences")
    if isinstance(sequences, dict) and isinstance(sequences.get("names"), list):
        subjects = sorted({str(s) for s in sequences.get("subjects", []) if s}, key=lambda s: (len(s), s))
        rows.append(["sequences trained on", f"{len(sequences['names'])}" + (
            f" ({len(subjects)} subject(s): {', '.join(subjects)})" if subjects else "")])
    frames = recorded_train_frames(training)
    if frames is not None:
        rows.append(["frames trained on", f"{frames:,}"])
    return rows


def trained_frame_count(training: dict, data: LearningData) -> int:
    """The frames the model trained on: as its model.pt records them, or (one that records none) the train split,
    with the held-out frames for an oracle."""
    frames = recorded_train_frames(training)
    if frames is not None:
        return frames
    return len(data.train) + (len(data.held_out) if trained_on_held_out(training) else 0)


def recorded_train_frames(training: dict) -> int | None:
    """The frames a model.pt says it trained on (train's `train_frames`), or None where it records no count."""
    frames = training.get("train_frames")
    return frames if isinstance(frames, int) and not isinstance(frames, bool) and frames > 0 else None


def trained_on_held_out(training: dict) -> bool:
    """Whether the model.pt's training says it trained on the held-out frames (train's --train-on)."""
    return isinstance(training.get("train_on"), list) and "held_out" in training["train_on"]


def _test_note(data: LearningData) -> str:
    """How the test frames were drawn, in words."""
    rule = data.test_split
    if rule.kind != WINDOWS:
        return ("Test: a random share of the frames of the trained sequences (the paper's split: most test frames "
                "have a trained neighbour a frame away).")
    return (f"Test: contiguous blocks of up to {rule.window:g} s of the trained sequences, no frame trained on "
            f"within {rule.guard:g} s of a test frame (in its run or in its library file's motion): the "
            f"{len(data.guard)} frames that near one (guard frames) are in no split.")


def _motion_kind_sections(by_kind: dict[str, GroupErrors], dropped: tuple[tuple[str, str], ...],
                          task: Task) -> list[Section]:
    """The errors per motion category and per subject (a dataset of library windows), and the sequences dropped
    on the way to the dataset with their reasons (if any)."""
    sections = []
    if by_kind:
        pieces: list = [Paragraphs(
            f"Errors (x 1e-3 scene units) of the network and of {task.predictor_label} alone (the predictor) over "
            f"the frames of each category of the library's manifest and of each subject, per split; gain = "
            f"predictor / network. `{NO_WINDOW}`: frames of sequences that play no library window (motion "
            f"programs, the settings' test clips).")]
        for grouping, groups in by_kind.items():
            header = [grouping, "split", "frames", "network L1", "predictor L1", "L1 gain", "network L2",
                      "predictor L2", "L2 gain"]
            splits = sorted(groups.frames, key=lambda name: name != "held_out")    # held out first: what it is for
            rows = [_group_row(groups, split, k) for split in splits for k in np.flatnonzero(groups.frames[split])]
            pieces.append(Table(header, rows))
        sections.append(Section("Errors by motion kind", pieces))
    if dropped:
        sections.append(Section("Dropped sequences", [
            Paragraphs(f"{len(dropped)} sequence(s) left out on the way to the dataset (a library window that "
                       f"could not be played, a run that blew up or tangled), each with its reason:"),
            Table(["sequence", "reason"], [[name, " ".join(reason.split())] for name, reason in dropped])]))
    return sections


def _group_row(groups: GroupErrors, split: str, k: int) -> list:
    """A row of a table by motion kind: group k's frames in `split`, and per term the network's and predictor's
    errors (x 1e-3) and the gain."""
    cells = [groups.labels[k], SPLIT_NAMES[split], int(groups.frames[split][k])]
    for term in TERMS:
        network, predictor = (groups.errors[split][who][term][k] / PAPER_UNIT for who in WHO)
        cells += [f"{network:.3f}", f"{predictor:.3f}", f"{predictor / max(network, 1e-30):.2f}x"]
    return cells


def _report_sections(args, state, data: LearningData, errors, times, device: str, n_low: int,
                     train_log: TrainLog | None, pictures: list[Path], plots: dict[str, Path],
                     videos: list[tuple[Path, str]], files: list[tuple[str, str]], task: Task,
                     by_kind: list[Section]) -> list[Section]:
    """The report's contents, as pieces both report.md and report.html show; `by_kind` follows the errors."""
    spec, training = state["spec"], state["training"]
    scaled = lambda who, split, term: errors[who][split][term] / PAPER_UNIT  # noqa: E731
    splits = list(data.splits())
    header = ["", *[f"{SPLIT_NAMES[s]} {t}" for s in splits for t in ("L1", "L2")], "test Ln"]
    rows = [[label, *[f"{scaled(who, s, t):.3f}" for s in splits for t in ("l1", "l2")],
             f"{errors[who]['test']['normal']:.4f}"]
            for who, label in (("network", "network"), ("predictor", f"{task.predictor_label} alone (predictor)"))]
    gains = [scaled("predictor", s, t) / max(scaled("network", s, t), 1e-30) for s in splits for t in ("l1", "l2")]
    rows.append(["gain (predictor / network)", *[f"{g:.2f}x" for g in gains], ""])
    rows += task.extra_error_rows(errors, splits)
    held_note = ""
    if trained_on_held_out(training):
        held_note = ("**The held-out frames were trained on** (training.train_on: train, held_out): this network is "
                     "the oracle, and its held-out error is the architecture's ceiling on the motion clip(s) "
                     f"`{data.held_out_clips}`, not a measure of generalisation. ")
    elif "held_out" in splits:
        held_note = (f"Held-out: every frame of the motion clip(s) `{data.held_out_clips}`, never seen in training "
                     "(the generalisation test). ")
    held_note += _test_note(data) + "\n\n" + task.error_note(data)
    loss = training["loss_weights"]
    training_rows = [["epochs", training["epochs"]], ["device", training["device"]],
                     ["batch size", training["batch_size"]], ["Adam learning rate", f"{training['lr']:g}"],
                     ["seed", training["seed"]],
                     ["loss weights L1 / L2 / Ln", f"{loss['l1']:g} / {loss['l2']:g} / {loss['normal']:g}"],
                     *_training_option_rows(training)]
    if train_log is not None:
        training_rows += [["last epoch's train loss", float(train_log.train_total[-1])],
                          ["last epoch's test loss", float(train_log.test_total[-1])]]
    guard = f", {len(data.guard)} guard (in no split)" if len(data.guard) else ""
    input_rows = [["dataset", args.dataset],
                  *([["garment", f"{args.garment} (the user's file, dressed on the mannequin: dressed.h5)"]]
                    if args.garment else []),
                  *([["hand", f"{args.hand_files} (the user's files: hand.h5)"]] if args.hand_files else []),
                  ["frames", ", ".join(f"{len(ids)} {SPLIT_NAMES[name]}" for name, ids in data.splits().items())
                   + guard],
                  *task.input_rows(data, state, n_low)]
    error_pieces = [Table(header, rows), Paragraphs(
        held_note + "L1 = mean over vertices of |x_truth - x|_1 / 3 (eq. 4); L2 = sqrt(mean over vertices of "
        "|x_truth - x|^2) (eq. 5), both over all frames of a split; Ln = face-normal L1 (eq. 6, dimensionless).")]
    if "error_over_time" in plots:
        error_pieces.append(Picture(plots["error_over_time"], "L1 of each test and held-out frame, for the network "
                                    f"and for {task.predictor_label} alone; dashed lines: where a sequence "
                                    f"starts."))
    training_pieces: list = [Table(["", "value"], training_rows)]
    shown_input = task.input_label[:1].upper() + task.input_label[1:]
    if "training_curve" in plots:
        training_pieces.append(Picture(plots["training_curve"], "Loss per epoch, train and test (log scale)."))
    sections = [
        Section("Network", [Paragraphs(
            f"{state['arch_expanded']} ({task.network.name}), conv "
            f"{spec['conv']}, {spec['pool']} pooling, width "
            f"{spec['width']:g}: **{state['parameter_count']:,} learnable parameters**.")]),
        Section("Errors (x 1e-3 scene units, as paper Table 3)", error_pieces),
        *by_kind,
    ]
    if videos:
        sections.append(Section("Videos", [Paragraphs(
            f"{shown_input} | {task.truth_label} | network output | |error| of the network, through one camera "
            "and on one colour scale for every frame, the stills' too (saturating at the 99th percentile of the "
            "errors of every frame shown).")] + [Video(path, caption) for path, caption in videos]))
    if pictures:
        sections.append(Section("Renders", [Paragraphs(
            f"Test (and held-out) frames: {task.input_label} | {task.truth_label} | network output | |error| of "
            f"{task.predictor_label} alone | |error| of the network (one colour scale, saturating at the 99th "
            "percentile of the errors of every frame shown).")] + [Picture(path, path.stem) for path in pictures]))
    sections += [
        Section("Inputs", [Table(["", "value"], input_rows)]),
        Section("Training", training_pieces),
        Section("Inference time", [Paragraphs(
            f"Median **{np.median(times):.2f} ms per frame** on {device} on the deployment path ({times.path}; "
            f"{task.timed}, one frame per call, {len(times)} test frame(s) timed "
            f"after {WARMUP_RUNS} warm-up runs; min {times.min():.2f}, max {times.max():.2f} ms); eager PyTorch on "
            f"the same frames: median {np.median(times.eager):.2f} ms. {_fused_sentence(times)}"
            f"{task.timing_note(args.dataset, float(np.median(times)))}{task.timing_reference}")]),
        Section("Files", [Links(files)]),
    ]
    return sections


def _fused_sentence(times) -> str:
    """What a user deploys on CUDA, beside the fp32 path: the fused bf16 network's median and its error (none
    where it was not timed: the CPU, a decoder)."""
    if times.fused is None:
        return ""
    return (f"The fused bf16 network ({times.fused.path}) on the same frames: median "
            f"**{np.median(times.fused.ms):.2f} ms**, within {times.fused.error:.1e} of the fp32 path's output "
            f"(largest difference over its largest displacement). ")


if __name__ == "__main__":
    cli.run(main)
