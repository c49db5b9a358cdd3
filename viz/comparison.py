"""One frame of cloth upsampling as a picture: the low-res input, the high-res ground truth and the network's
output (on the body, where there is one), then the |error| maps; the stills and the video frames of a report.

Every frame of a report goes through one `Comparison`: one camera (a video holds still, stills compare) and one
colour scale for every error map, so a colour means the same error in every picture.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from viz.render import Panel, View, fit_view, panels_image


@dataclasses.dataclass(frozen=True)
class Comparison:
    """What every frame of a report shares: the meshes' faces, the camera and the error colour scale."""

    low_faces: np.ndarray          # (T_low, 3)
    faces: np.ndarray              # (T_high, 3)
    view: View
    vmax: float                    # |error| at the top of the colour bar (scene units)
    value_label: str = "|error| (scene units)"
    input_label: str = "low-res input"            # the first panel: what the network is given, as a mesh
    predictor_label: str = "Loop subdivision"     # what the network's output is added to
    truth_label: str = "high-res ground truth"    # what the network is trained towards (the hand's: its FEM)


@dataclasses.dataclass(frozen=True)
class FrameMeshes:
    """One frame's positions: low-res input, its Loop subdivision (the predictor), truth and network output."""

    low: np.ndarray                # (V_low, 3)
    predictor: np.ndarray          # (V, 3) S x_low
    truth: np.ndarray              # (V, 3)
    predicted: np.ndarray          # (V, 3)
    body: tuple[np.ndarray, np.ndarray] | None = None     # the mannequin's mesh (vertices, faces) this frame


def fit_comparison(low: Sequence[np.ndarray], truth: Sequence[np.ndarray], low_faces: np.ndarray,
                   faces: np.ndarray, errors: Sequence[np.ndarray], error_percentile: float = 99.0,
                   input_label: str = "low-res input", predictor_label: str = "Loop subdivision",
                   truth_label: str = "high-res ground truth") -> Comparison:
    """The camera framing the garment of every frame to be shown (its low-res input and ground truth: a wild
    network output leaves the frame instead of shrinking the cloth in it), and the colour scale saturating at
    `error_percentile` of `errors` (per-vertex |error| arrays): a few large boundary errors would otherwise wash
    out the pattern."""
    view = fit_view([*low, *truth])
    values = np.concatenate([np.ravel(e) for e in errors]) if len(errors) else np.zeros(1)
    return Comparison(low_faces, faces, view, float(np.percentile(values, error_percentile)),
                      input_label=input_label, predictor_label=predictor_label, truth_label=truth_label)


def comparison_image(comparison: Comparison, frame: FrameMeshes, title: str, predictor_error: bool = True,
                     panel_height: float = 4.5, supersample: int = 2) -> np.ndarray:
    """RGB uint8 image: low-res input | ground truth | network output (each on the body) | |error| of Loop
    subdivision alone (if `predictor_error`) | |error| of the network, through the comparison's camera."""
    c = comparison
    panels = [Panel(c.input_label, frame.low, c.low_faces, backdrop=frame.body),
              Panel(c.truth_label, frame.truth, c.faces, backdrop=frame.body),
              Panel("network output", frame.predicted, c.faces, backdrop=frame.body)]
    if predictor_error:
        panels.append(Panel(f"error: {c.predictor_label}", frame.truth, c.faces,
                            np.linalg.norm(frame.truth - frame.predictor, axis=1)))
    panels.append(Panel("error: network", frame.predicted, c.faces,
                        np.linalg.norm(frame.truth - frame.predicted, axis=1)))
    return panels_image(panels, c.view, c.vmax, title, c.value_label, panel_height, supersample=supersample)
