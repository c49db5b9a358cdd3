"""Training loop (paper section 4: Adam, lr 1e-3, betas 0.9/0.999, eps 1e-8, batch size 3) with per-epoch
checkpoints that a killed run resumes from, ending where an uninterrupted run with the same seed ends.

Everything random after the network's initialisation is the epoch's draw of frames (model.sampler), drawn from
its own generator whose state travels in the checkpoint with the sampler's;
with `torch.use_deterministic_algorithms` a resumed run repeats the same
arithmetic as an uninterrupted one.

A checkpoint is a dict of tensors and plain Python values only (dicts, lists, str, int, float, bool, None), so
whoever stores it can read it back with `torch.load(weights_only=True)`, which builds nothing else: a file from
elsewhere can be refused but never runs code. Where it is stored is the caller's business (`fit` takes the state
to resume from and a function that saves each new one).
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Callable, Iterator, Mapping, Protocol

import torch

from model import data_parallel
from model.autoregressive import pushforward_inputs, reads_previous_output
from model.data_parallel import SINGLE, Ranks
from model.features import FrameBatch, FrameStore
from model.losses import LossWeights, l1_loss, l2_loss, normal_loss, total_loss
from model.mesh_hierarchy import MeshHierarchy
from model.sampler import Sampler, SampleSettings
from model.training_step import (DDP_WARMUP_STEPS, LOSS_TERMS, WARMUP_STEPS, BatchLoss, GraphedStep, adam,
                                 eager_step, learning_rate, set_learning_rate)

# 1 pickled a History object. One of format 2 written before the sampler existed holds other settings (its
# identity has no `sampling`), so it is not resumed but started afresh.
CHECKPOINT_FORMAT = "trimesh-cnn/checkpoint-2"
TERMS = ("total", *LOSS_TERMS)
# Frames a split's errors are computed together after each epoch. No backward: memory allows far more than a
# training batch, and at a batch of 3 the pass is launch-bound: with a sample share of 0.1 an epoch trains on a
# tenth of the training frames but scores every test frame (as many as that tenth).
SPLIT_BATCH = 32
# The test frames scored after each epoch: at most this many, evenly spaced through the split. The per-epoch test
# loss is a monitor (the evaluate stage scores every frame); a library's 12k test frames would otherwise cost each
# epoch of a tenth of the training frames as much again, and a study point's many short epochs far more.
MONITORED_TEST_FRAMES = 4096


@dataclasses.dataclass(frozen=True)
class TrainSettings:
    epochs: int
    batch_size: int = 3
    lr: float = 1e-3
    weights: LossWeights = LossWeights()
    seed: int = 0
    cuda_graph: bool = False     # replay each full batch's step as one CUDA graph (model.training_step)
    input_noise: float = 0.0     # std of the noise on the normalised inputs (model.feature_regressor.with_input_noise)
    lr_schedule: str = "constant"   # or "cosine" (model.training_step.learning_rate), over all epochs' steps
    sampling: SampleSettings = SampleSettings()   # which training frames an epoch visits (model.sampler)


@dataclasses.dataclass
class History:
    """Per-epoch mean losses on the training frames (as seen during the epoch) and on the test frames (after
    it), each batch's total loss, and each epoch's wall time."""

    train: dict[str, list[float]] = dataclasses.field(default_factory=lambda: {t: [] for t in TERMS})
    test: dict[str, list[float]] = dataclasses.field(default_factory=lambda: {t: [] for t in TERMS})
    batch_total: list[float] = dataclasses.field(default_factory=list)
    epoch_seconds: list[float] = dataclasses.field(default_factory=list)
    resumed_from_epoch: int = 0

    @property
    def epochs_done(self) -> int:
        return len(self.epoch_seconds)


class CheckpointError(ValueError):
    """A checkpoint written for this run (format and identity match) whose contents cannot be restored."""


class Diverged(ValueError):
    """An epoch whose training or test loss is NaN or infinite: the weights have overflowed, so training on
    would only save and report a useless network (the learning rate is too high for the data)."""


def in_batches(ids: torch.Tensor, batch_size: int) -> Iterator[torch.Tensor]:
    """`ids` cut into batches of `batch_size` (the last one shorter)."""
    for start in range(0, len(ids), batch_size):
        yield ids[start:start + batch_size]


@dataclasses.dataclass(frozen=True)
class Frames:
    """The learning problem on one device: what the network's inputs are made from (the store's predictor is
    S x_low), the target displacements, the mesh faces. Every frame resident; model.streaming.StreamedFrames
    reads them from disk a batch at a time."""

    store: FrameStore
    targets: torch.Tensor    # (F, V, 3)
    faces: torch.Tensor      # (n_faces, 3) int64

    def feed(self, ids: torch.Tensor, batch_size: int) -> Iterator[torch.Tensor]:
        """The ids to gather each batch of the frames `ids` by, in order (here: the frames' own ids)."""
        return in_batches(ids, batch_size)

    def all_frames(self) -> tuple[FrameStore, torch.Tensor]:
        """A store and targets of every frame, indexable by frame id (for the normalisation's statistics)."""
        return self.store, self.targets

    def batch_loss(self, model, mesh: MeshHierarchy, ids: torch.Tensor,
                   weights: LossWeights) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Eq. 7 over the frames `ids` taken together, and its terms (model.losses.total_loss)."""
        inputs = self.inputs(model, mesh, ids)
        return total_loss(inputs.positions + model(inputs, mesh), inputs.positions + self.targets[ids], self.faces,
                          weights)

    def inputs(self, model, mesh: MeshHierarchy, ids: torch.Tensor) -> FrameBatch:
        """What `model` is given for the frames `ids`: their inputs, and for a network that reads its previous
        output its own at each previous frame (model.autoregressive)."""
        if reads_previous_output(model):
            return pushforward_inputs(lambda inputs: model(inputs, mesh), self.store, ids)
        return self.store.batch(ids)

    def errors(self, model, mesh: MeshHierarchy, ids: torch.Tensor, batch_size: int,
               weights: LossWeights) -> dict[str, float]:
        return split_errors(lambda inputs: model(inputs, mesh), self, ids, batch_size, weights,
                            lambda batch: self.inputs(model, mesh, batch))


class Problem(BatchLoss, Protocol):
    """What `fit` trains on: the loss of a batch of sample ids (BatchLoss) and the errors over a split's
    sample ids, for a model on `mesh`. `Frames` is one mesh's problem (a sample is a frame);
    model.multi_mesh.MultiMeshFrames trains one network on several meshes (a sample is one frame of each)."""

    def errors(self, model, mesh, ids: torch.Tensor, batch_size: int, weights: LossWeights) -> dict[str, float]: ...

    def feed(self, ids: torch.Tensor, batch_size: int) -> Iterator[torch.Tensor]:
        """What the step is given for each batch of the sample ids `ids` (Frames.feed)."""


def split_errors(predict: Callable[[FrameBatch], torch.Tensor], frames: Frames, ids: torch.Tensor,
                 batch_size: int, weights: LossWeights,
                 inputs_of: Callable[[torch.Tensor], FrameBatch] | None = None) -> dict[str, float]:
    """L1 (eq. 4), L2 (eq. 5), Ln (eq. 6) and their weighted total over all frames `ids` taken together;
    `predict` maps a batch of frames (`inputs_of` the ids Frames.feed yields: by default the store's batch) to
    predicted displacements. Positions are S x_low + displacement."""
    def batches():
        for batch in frames.feed(ids, batch_size):
            inputs = (inputs_of or frames.store.batch)(batch)
            yield batch, inputs.positions, predict(inputs)
    with torch.no_grad():
        return _errors(batches(), frames, len(ids), weights)


def _errors(batches, frames: Frames, count: int, weights: LossWeights) -> dict[str, float]:
    """The errors of (frame ids, S x_low, predicted displacement) batches over `count` frames in all."""
    sums = []      # per batch (l1, l2², normal) × its frame count, on the device until the end (no per-batch wait)
    for batch, positions, displacement in batches:
        predicted, truth = positions + displacement, positions + frames.targets[batch]
        sums.append(torch.stack([l1_loss(predicted, truth), l2_loss(predicted, truth) ** 2,
                                 normal_loss(predicted, truth, frames.faces)]) * len(batch))
    return split_values(*(torch.stack(sums).sum(dim=0) / count).tolist(), weights)


def split_values(l1: float, l2_squared: float, normal: float, weights: LossWeights) -> dict[str, float]:
    """A split's errors from its mean L1, L2 squared and Ln over its frames: L2 is the root of the mean, and
    the total eq. 7 with `weights`."""
    errors = {"l1": l1, "l2": l2_squared ** 0.5, "normal": normal}
    errors["total"] = weights.l1 * errors["l1"] + weights.l2 * errors["l2"] + weights.normal * errors["normal"]
    return errors


def fit(model: torch.nn.Module, mesh: MeshHierarchy | Mapping[str, MeshHierarchy], frames: Problem,
        train_ids: torch.Tensor, test_ids: torch.Tensor, settings: TrainSettings,
        resume_from: dict[str, Any] | None = None, save_checkpoint: Callable[[dict[str, Any]], None] | None = None,
        identity: dict[str, Any] | None = None,
        on_batch: Callable[[int, torch.Tensor], None] = lambda epoch, loss: None,
        on_notice: Callable[[str], None] = print, ranks: Ranks = SINGLE) -> History:
    """Train `model` in place for `settings.epochs` epochs; returns the loss history. `frames` says what a
    batch's loss and a split's errors are (a `Frames`, or another `Problem`), `mesh` what it runs `model` on.

    `save_checkpoint(state)`, if given, is called after every epoch with the whole training state (see the
    module docstring); given such a state as `resume_from`, training resumes from it if it was written for the
    same `identity` (settings, data and operators fingerprints) and starts afresh otherwise, saying why through
    `on_notice`. Raises CheckpointError for a matching state that cannot be restored. `on_batch(epoch, loss)`
    is called after every optimiser step with the batch's loss as a 0-d tensor on the device (reading it makes
    the host wait for the GPU: read it now and then, not every step).

    `ranks` of several processes train `model.net` with DistributedDataParallel (model.data_parallel: the
    process group must be started), `settings.batch_size` frames a rank and step; the history is every rank's
    frames', and only rank 0 calls `save_checkpoint`.
    """
    model.input_noise = settings.input_noise
    optimizer = adam(model, settings.lr, settings.cuda_graph, scheduled=settings.lr_schedule != "constant")
    step = eager_step(model, mesh, frames, optimizer, settings.weights)
    if settings.cuda_graph:
        step = GraphedStep(step, settings.batch_size, train_ids.device,
                           DDP_WARMUP_STEPS if ranks.parallel else WARMUP_STEPS)
    shuffle = torch.Generator().manual_seed(settings.seed)
    sampler = Sampler(len(train_ids), settings.sampling)
    # A checkpoint of another number of ranks is another run (each step's frames differ).
    identity = {"settings": _settings_key(settings), **(identity or {}), **({"ranks": ranks.size} if ranks.parallel
                                                                             else {})}
    if ranks.parallel:
        # Every rank's input noise its own: seeded by the run's seed and the rank (the weights are seeded already).
        torch.manual_seed(settings.seed * 65_537 + ranks.rank)
    history = History()
    if resume_from is not None:
        history = _resume(resume_from, identity, settings.epochs, model, optimizer, shuffle, sampler, on_notice,
                          train_ids.device, ranks)
    steps_per_epoch = data_parallel.steps_of(sampler.frames_per_epoch, settings.batch_size, ranks)
    monitored = data_parallel.my_part(monitored_test_frames(test_ids), ranks)
    with data_parallel.distributed(model, ranks):
        for epoch in range(history.epochs_done, settings.epochs):
            start = time.perf_counter()
            model.train()
            order = train_ids[sampler.epoch(shuffle).to(train_ids.device)]
            mine, last_weight = data_parallel.step_share(order, settings.batch_size, ranks)
            last = data_parallel.steps_of(len(order), settings.batch_size, ranks) - 1
            # The losses stay on the device until the epoch ends: a `.item()` per step would make the host wait
            # for the GPU at every step, and a launch-bound step then costs the host's time plus the GPU's.
            values, counts = [], []
            for index, batch in enumerate(frames.feed(mine, settings.batch_size)):
                if settings.lr_schedule != "constant":
                    set_learning_rate(optimizer, learning_rate(settings.lr_schedule, settings.lr,
                                                               epoch * steps_per_epoch + index,
                                                               settings.epochs * steps_per_epoch))
                weight = last_weight if index == last else 1.0
                values.append(step(batch, weight))
                counts.append(len(batch) if weight else 0)       # a weight-0 frame only keeps the rank in step
                on_batch(epoch, values[-1][0])
            batch_totals, sums = _epoch_losses(torch.stack(values), counts, ranks)
            history.batch_total.extend(batch_totals)
            for name, total in zip(TERMS, sums):
                history.train[name].append(total / len(order))
            model.eval()
            # A rank may have no test frame to score (fewer test frames than ranks): it adds nothing to the sums.
            test = frames.errors(model, mesh, monitored, split_batch_size(settings.batch_size), settings.weights) \
                if len(monitored) or not ranks.parallel else None
            if ranks.parallel:
                test = data_parallel.combined_errors(test, len(monitored), ranks, settings.weights,
                                                     train_ids.device)
            for name in TERMS:
                history.test[name].append(test[name])
            history.epoch_seconds.append(time.perf_counter() - start)
            _check_finite(history, epoch)
            noise = _noise_state(train_ids.device, ranks)      # every rank's, gathered: a collective
            if save_checkpoint is not None and ranks.main:
                save_checkpoint({"format": CHECKPOINT_FORMAT, "identity": identity, "model": model.state_dict(),
                                 "optimizer": optimizer.state_dict(), "shuffle": shuffle.get_state(),
                                 "sampler": sampler.state(), "noise": noise,
                                 "history": dataclasses.asdict(history)})
    model.eval()
    return history


def _epoch_losses(values: torch.Tensor, counts: list[int], ranks: Ranks) -> tuple[list[float], list[float]]:
    """Each step's total loss and the epoch's sums of each term x frames, over every rank's frames, from this
    rank's steps' loss terms `values` (steps, 4) and frame counts. One process: its own (the arithmetic it has
    always done); several: each step's loss the frame-weighted mean of the ranks' (one reduction an epoch)."""
    weighted = values * torch.tensor(counts, dtype=values.dtype, device=values.device)[:, None]
    if not ranks.parallel:
        return values[:, 0].tolist(), weighted.sum(dim=0).tolist()
    per_step = data_parallel.sum_over_ranks(
        torch.cat([weighted, torch.tensor(counts, dtype=values.dtype, device=values.device)[:, None]], dim=1), ranks)
    return (per_step[:, 0] / per_step[:, -1]).tolist(), per_step[:, :-1].sum(dim=0).tolist()


def _check_finite(history: History, epoch: int) -> None:
    losses = {"training": history.train["total"][-1], "test": history.test["total"][-1]}
    for split, loss in losses.items():
        if not math.isfinite(loss):
            raise Diverged(f"the {split} loss of epoch {epoch + 1} is {loss}: the weights overflowed; lower the "
                           f"learning rate")


def monitored_test_frames(test_ids: torch.Tensor) -> torch.Tensor:
    """The test frames each epoch scores: all of them up to MONITORED_TEST_FRAMES, else that many evenly spaced."""
    if len(test_ids) <= MONITORED_TEST_FRAMES:
        return test_ids
    return test_ids[torch.linspace(0, len(test_ids) - 1, MONITORED_TEST_FRAMES).round().long().to(test_ids.device)]


def split_batch_size(batch_size: int) -> int:
    """The frames a split's errors take together after each epoch (a streamed problem stages this many)."""
    return max(batch_size, SPLIT_BATCH)


def _noise_state(device: torch.device, ranks: Ranks = SINGLE) -> torch.Tensor:
    """The state of the generator that input noise draws from (torch's default one on `device`): saved so that
    a resumed run draws the noise the uninterrupted one would have; of several ranks every rank's, one row each."""
    state = torch.cuda.get_rng_state(device) if device.type == "cuda" else torch.get_rng_state()
    return data_parallel.gather_over_ranks(state, ranks) if ranks.parallel else state


def _restore_noise_state(state: torch.Tensor, device: torch.device, ranks: Ranks = SINGLE) -> None:
    if ranks.parallel:
        state = state[ranks.rank].clone()     # its own storage: set_rng_state reads a view's from its start
    if device.type == "cuda":
        torch.cuda.set_rng_state(state, device)
    else:
        torch.set_rng_state(state)


def _resume(state: dict[str, Any], identity: dict[str, Any], epochs: int, model: torch.nn.Module,
            optimizer: torch.optim.Optimizer, shuffle: torch.Generator, sampler: Sampler,
            on_notice: Callable[[str], None], device: torch.device, ranks: Ranks = SINGLE) -> History:
    """Restore model, optimiser, shuffle and sampler states from a matching checkpoint; a fresh History
    otherwise."""
    if not (isinstance(state, dict) and state.get("format") == CHECKPOINT_FORMAT
            and state.get("identity") == identity):
        on_notice("checkpoint written for other settings, data or operators: starting afresh")
        return History()
    try:
        history = _history_of(state["history"])
        if history.epochs_done > epochs:
            on_notice(f"checkpoint of a longer run ({history.epochs_done} epochs): starting afresh")
            return History()
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        shuffle.set_state(state["shuffle"])
        sampler.restore(state["sampler"])
        if "noise" in state:       # checkpoints written before input noise existed have none
            _restore_noise_state(state["noise"], device, ranks)
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, RuntimeError) as err:
        # The message of a failed load_state_dict spans lines; the type is enough to say it is damaged.
        raise CheckpointError(f"checkpoint contents cannot be restored ({type(err).__name__})") from None
    history.resumed_from_epoch = history.epochs_done
    on_notice(f"resuming after epoch {history.epochs_done}")
    return history


def _history_of(plain: dict[str, Any]) -> History:
    """The History saved as `dataclasses.asdict`, checked for one loss value per epoch of every term."""
    history = History(**plain)
    lengths = {len(history.train[t]) for t in TERMS} | {len(history.test[t]) for t in TERMS}
    if lengths != {history.epochs_done}:
        raise ValueError("loss history with different epoch counts per term")
    return history


def _settings_key(settings: TrainSettings) -> dict[str, Any]:
    # Not the epoch count: a checkpoint of a shorter run is a valid start for a longer one, unless the rate is
    # scheduled over all the epochs (a shorter cosine has decayed further at the same step).
    key = dataclasses.asdict(settings)
    if settings.lr_schedule == "constant":
        key.pop("epochs")
    return key
