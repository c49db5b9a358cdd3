"""The solver kinds the simulate stage can step, keyed by a scene's `solver.kind` (workflow/config.schema.yaml).
Absent means xpbd, so settings written before the key existed stay valid and rerun nothing. A new kind brings its
solver (sim/<name>/), its adapter here (pipeline/solvers/<name>.py: its levels) and, in scenes/, the scene builder
that makes what its adapter reads; the stage stays as it is."""
from __future__ import annotations

from pipeline.core.errors import PipelineError
from pipeline.solvers import xpbd
from pipeline.solvers.level import Level

DEFAULT_KIND = "xpbd"

# kind -> its levels (the runs it makes of a sequence) by name
KINDS: dict[str, dict[str, Level]] = {"xpbd": xpbd.LEVELS}


def level_names() -> list[str]:
    """Every kind's level names, each once, in the order the kinds list them: what the stage's CLI takes."""
    return list(dict.fromkeys(name for levels in KINDS.values() for name in levels))


def solver_level(settings: dict, level: str, source: str) -> Level:
    """The level `level` of the settings' solver kind; an error naming `source` (the settings file) for a kind or
    a level that is not there."""
    kind = settings["solver"].get("kind", DEFAULT_KIND)
    if kind not in KINDS:
        raise PipelineError(f"{source}: solver.kind '{kind}' is not a kind the simulate stage steps (it steps: "
                            f"{', '.join(KINDS)}; a hand scene's fem runs through pipeline.hand_simulate)")
    if level not in KINDS[kind]:
        raise PipelineError(f"{source}: the {kind} solver makes no '{level}' run (its runs: "
                            f"{', '.join(KINDS[kind])})")
    return KINDS[kind][level]
