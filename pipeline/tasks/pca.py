"""PCA details recovery (paper section 5.2, Fig. 10, Table 4 "cape PCA"): a PCA of the high-res run's training
frames (reference frame) with K components; the input is a frame's K coefficients, the predictor its PCA
reconstruction, and the decoder regresses what the truncation lost. The PCA sees training frames only, so test
and held-out frames are compressed by a basis that never saw them, as a reduced-order simulation would be.

The basis is fitted to at most FIT_FRAMES training frames, evenly spread (a paper-profile scene has ~45k frames
of ~40k coordinates: their full matrix would not fit in memory).
"""
from __future__ import annotations

import numpy as np

from pipeline.artifacts.dataset import LearningData, PcaBasis, TaskLayout
from pipeline.core.errors import PipelineError
from pipeline.tasks.decoder import DecoderTask, decoder_frames
from pipeline.tasks.task import DatasetRequest, SequenceRun

FIT_FRAMES = 2048


def fit_pca(frames: np.ndarray, n_components: int) -> PcaBasis:
    """The first `n_components` principal components of frames (m, V, 3)."""
    flat = frames.reshape(len(frames), -1)
    mean = flat.mean(axis=0)
    _, singular_values, vt = np.linalg.svd(flat - mean, full_matrices=False)
    total = float(np.square(singular_values).sum())
    kept = singular_values[:n_components]
    return PcaBasis(mean.reshape(frames.shape[1:]), vt[:n_components].reshape(n_components, *frames.shape[1:]),
                    kept, float(np.square(kept).sum()) / total if total > 0 else 1.0, len(frames))


def project(basis: PcaBasis, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients (n, K) of positions (n, V, 3) and their reconstruction (n, V, 3)."""
    components = basis.components.reshape(len(basis.components), -1)
    coefficients = (positions.reshape(len(positions), -1) - basis.mean.reshape(-1)) @ components.T
    return coefficients, (basis.mean.reshape(-1) + coefficients @ components).reshape(positions.shape)


class PcaTask(DecoderTask):
    name = "pca"
    predictor_label = "PCA reconstruction"
    input_label = "PCA reconstruction"
    input_description = "PCA coefficients of the high-res run"
    timing_reference = ("Paper Table 4 (RTX 2080 Ti, cape PCA 32 / 64, RC13 decoder): 9.3 ms for 5,746 vertices.")

    def prepare(self, request: DatasetRequest):
        k = request.components
        train = request.layout.split.train
        if k is None or k < 1:
            raise PipelineError("task pca needs --components K >= 1")
        fitted = train[np.unique(np.linspace(0, len(train) - 1, min(FIT_FRAMES, len(train))).round().astype(int))]
        if len(fitted) <= k:
            raise PipelineError(f"task pca: {k} components need more than {k} training frames, the dataset has "
                                f"{len(train)}")
        basis = fit_pca(_gather(request.runs(), fitted), k)

        def frames(run: SequenceRun):
            coefficients, reconstruction = project(basis, run.high)
            return decoder_frames(run, coefficients, reconstruction)

        layout = TaskLayout(self.name, k, f"PCA details recovery, {k} components (paper Table 2)",
                            f"the {k} PCA coefficients of the high-res frame (F, {k}): input . components = "
                            f"x_high - mean", f"the PCA reconstruction mean + sum_k input[k] components[k], per "
                            f"frame (F, V_high, 3), in the reference frame", basis)
        return layout, frames

    def extra_error_rows(self, errors: dict, splits: list[str]) -> list[list]:
        recovered = [1.0 - errors["network"][s][t] / max(errors["predictor"][s][t], 1e-30)
                     for s in splits for t in ("l1", "l2")]
        return [["share of the PCA truncation error recovered", *[f"{r:.0%}" for r in recovered], ""]]

    def error_note(self, data: LearningData) -> str:
        pca = data.pca
        return (f"The predictor is the {len(pca.components)}-component PCA reconstruction (fitted to "
                f"{pca.fitted_frames} training frames, holding {pca.explained:.2%} of their variance): its error "
                f"is the truncation error, and the share recovered is 1 - network / predictor. ")


def _gather(runs, ids: np.ndarray) -> np.ndarray:
    """The high-res positions of the frames `ids` (sorted dataset frame ids) from the runs in dataset order."""
    parts, start = [], 0
    for run in runs:
        mine = ids[(ids >= start) & (ids < start + len(run.high))] - start
        parts.append(run.high[mine])
        start += len(run.high)
    return np.concatenate(parts)
