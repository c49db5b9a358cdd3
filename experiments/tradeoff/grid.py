"""The trade-off's grid as the workflow lays it out (workflow/rules/tradeoff.smk, `results/<scene>/tradeoff/`):
from a scene's name, its resolved settings and its sequence names, the low-res budgets and the networks fed each,
the high-res runs beside the scene's own, their folders and timing runs, each budget's and run's settings overlay,
and the `experiments.tradeoff` stage's argument list and inputs.

The scene's own budget reuses the scene's runs and dataset.h5; its own high-res run is the ground truth, never a
row. The stage times the solvers of the speedup itself (the budgets' low-res runs and the free high-res run, the
paper's reference) on the scene's first sequence, in its own job; a sharded scene (`shard` > 1) simulates by batch,
so each high-res run beside the scene's is also run for its first sequence alone, whose solver timing is the row's.
The Snakefile imports this at every start: it reads settings only and imports nothing heavy.
"""
from __future__ import annotations

from typing import Any

from pipeline.core.config import shared_settings, simulation_settings
from pipeline.workflow_paths import settled_runs

Settings = dict[str, Any]
# (substeps, iterations, harmonic schedule) of a high-res run; wildcards give the numbers as strings.
HighResRun = tuple[int | str, int | str, str]
# (substeps, iterations) of a low-res budget. Its name (folder s<name>/, the wildcard, the stage's arguments) is
# "<substeps>" at the scene's iterations and "<substeps>x<iterations>" at others.
Budget = tuple[int, int]


def width_folder(width: float | str) -> str:
    """The folder name of a width: `:g`, so that the config's 0.5 and the wildcard's '0.5' agree."""
    return f"w{float(width):g}"


def own_budget(settings: Settings) -> Budget:
    return settings["solver"]["substeps"], settings["solver"]["iterations"]


def budget_of(settings: Settings, entry: int | list[int] | tuple[int, int]) -> Budget:
    """A config entry of `tradeoff.substeps` or `tradeoff.matched`: n substeps at the scene's iterations, or
    [substeps, iterations]."""
    return (int(entry), own_budget(settings)[1]) if isinstance(entry, (int, str)) else (int(entry[0]), int(entry[1]))


def budget_name(settings: Settings, budget: Budget) -> str:
    substeps, iterations = budget
    return str(substeps) if iterations == own_budget(settings)[1] else f"{substeps}x{iterations}"


def parse_budget_name(settings: Settings, name: int | str) -> Budget:
    """The budget of a name (budget_name's, as a wildcard gives it)."""
    substeps, _, iterations = str(name).partition("x")
    return int(substeps), int(iterations) if iterations else own_budget(settings)[1]


def budgets(settings: Settings) -> list[str]:
    """Every low-res budget of the grid by name, cheapest first (substeps, then iterations): `tradeoff.substeps`
    and the matched ones."""
    tradeoff = settings["tradeoff"]
    every = {budget_of(settings, entry) for entry in [*tradeoff["substeps"], *tradeoff["matched"]]}
    return [budget_name(settings, budget) for budget in sorted(every)]


def matched_budgets(settings: Settings) -> list[str]:
    """The budgets (names) with a network trained on their own inputs; at the scene's own that is the scene's
    network."""
    matched = {budget_of(settings, entry) for entry in settings["tradeoff"]["matched"]}
    return [budget_name(settings, budget) for budget in sorted(matched) if budget != own_budget(settings)]


def matched_nets(settings: Settings) -> list[str]:
    """The networks trained on a matched budget's own inputs (folder names under s<n>/): the scene's recipe, then
    the same recipe at each width of `tradeoff.matched_widths` (the cheapest learned paths a user would deploy)."""
    return ["matched", *[f"matched_{width_folder(w)}" for w in settings["tradeoff"]["matched_widths"]]]


def reference_run(settings: Settings) -> HighResRun:
    """The scene's own high-res run: the reference."""
    return (settings["solver"]["substeps"], settings["solver"]["iterations"], settings["high_res"]["harmonic_every"])


def high_res_runs(settings: Settings) -> list[HighResRun]:
    """Each high-res run beside the scene's, in config order, once: `tradeoff.high_res_budgets` with the scene's
    schedule, then the scene's budget with each schedule of `tradeoff.harmonic_every`; the reference left out."""
    tradeoff, own = settings["tradeoff"], reference_run(settings)
    runs = ([(n, i, own[2]) for n, i in tradeoff["high_res_budgets"]]
            + [(own[0], own[1], schedule) for schedule in tradeoff["harmonic_every"]])
    return [run for run in dict.fromkeys(runs) if run != own]


def point_folder(scene: str, name: int | str) -> str:
    """The folder of low-res budget `name`: its settings, runs, dataset and the networks fed it."""
    return f"results/{scene}/tradeoff/s{name}"


def point_sequence_folders(scene: str, name: int | str, sequences: list[str]) -> list[str]:
    """The budget's sequence folders, in the scene's order: its runs beside links to the scene's truth."""
    return [f"{point_folder(scene, name)}/sequences/{seq}" for seq in sequences]


def high_res_folder(scene: str, run: HighResRun) -> str:
    n, i, schedule = run
    return f"results/{scene}/tradeoff/h{n}x{i}_{schedule}"


def high_res_file(scene: str, run: HighResRun, seq: str) -> str:
    """Sequence `seq`'s high-res run `run`."""
    return f"{high_res_folder(scene, run)}/sequences/{seq}/sim_high.h5"


def high_res_files(scene: str, sequences: list[str], run: HighResRun) -> list[str]:
    return [high_res_file(scene, run, seq) for seq in sequences]


def high_res_timings(scene: str, settings: Settings) -> dict[HighResRun, str]:
    """A sharded scene's timing runs (one sequence alone) of the high-res runs beside the scene's, by run; none
    with `shard: 1` (each sequence's own job is timed)."""
    if settings["shard"] == 1:
        return {}
    return {run: f"{high_res_folder(scene, run)}/timing/sim_high.h5" for run in high_res_runs(settings)}


def scene_trained_nets(settings: Settings) -> list[str]:
    """The networks trained on the scene's budget: the scene's, then each smaller (folder names under s<n>/)."""
    return ["scene", *[width_folder(w) for w in settings["tradeoff"]["widths"]]]


def evaluation_file(scene: str, name: int | str, net: str) -> str:
    """eval.h5 of network `net` (scene, w<width>, matched or matched_w<width>) fed budget `name`."""
    return f"{point_folder(scene, name)}/{net}/eval.h5"


def network_model(scene: str, name: int | str, net: str) -> str:
    """model.pt of network `net` (scene, w<width>, matched or matched_w<width>) fed budget `name`."""
    if net == "scene":
        return f"results/{scene}/model.pt"
    if net.startswith("matched"):
        return f"{point_folder(scene, name)}/{net}/model.pt"
    return f"results/{scene}/tradeoff/{net}/model.pt"


def point_dataset(scene: str, settings: Settings, name: int | str) -> str:
    """The budget's dataset.h5: the scene's own at the scene's budget."""
    if parse_budget_name(settings, name) == own_budget(settings):
        return f"results/{scene}/dataset.h5"
    return f"{point_folder(scene, name)}/dataset.h5"


def low_runs(scene: str, settings: Settings, sequences: list[str], name: int | str) -> list[str]:
    """The budget's low-res run of each sequence: the scene's own at the scene's budget."""
    own = parse_budget_name(settings, name) == own_budget(settings)
    folder = f"results/{scene}" if own else point_folder(scene, name)
    return [f"{folder}/sequences/{seq}/sim_low.h5" for seq in sequences]


def solve_timing_files(scene: str, sequences: list[str]) -> list[str]:
    """What the stage times the solvers on: the first sequence's scene.h5 and low-res run at the scene's budget
    (where its high-res run starts), then the scene's settle runs (low, high) if it is a motion library's window."""
    first = f"results/{scene}/sequences/{sequences[0]}"
    return [f"{first}/scene.h5", f"{first}/sim_low.h5",
            *[run for level in ("low", "high") for run in settled_runs(scene, sequences[:1], level)]]


def stage_arguments(scene: str, settings: Settings, sequences: list[str]) -> list[str]:
    """`--solve-timing SCENE.h5 SIM_LOW.h5` [`--settled SETTLE_LOW.h5 SETTLE_HIGH.h5`], then `--point B SIM_LOW.h5`
    (B the budget's name: N substeps at the scene's iterations, or NxI; its run of the first sequence), `--eval B
    EVAL.h5 MODEL.pt` per network and `--matched B EVAL.h5 MODEL.pt` per matched network of each budget,
    `--high-res SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5 ...` for each high-res run, and a sharded scene's
    `--high-res-timing SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5`."""
    timing = solve_timing_files(scene, sequences)
    words: list[Any] = ["--solve-timing", *timing[:2], *(["--settled", *timing[2:]] if timing[2:] else [])]
    for n in budgets(settings):
        words += ["--point", n, low_runs(scene, settings, sequences, n)[0]]
        words += [x for net in scene_trained_nets(settings)
                  for x in ("--eval", n, evaluation_file(scene, n, net), network_model(scene, n, net))]
        if n in matched_budgets(settings):
            words += [x for net in matched_nets(settings)
                      for x in ("--matched", n, evaluation_file(scene, n, net), network_model(scene, n, net))]
    for run in high_res_runs(settings):
        words += ["--high-res", *run, *high_res_files(scene, sequences, run)]
    words += [x for run, path in high_res_timings(scene, settings).items() for x in ("--high-res-timing", *run, path)]
    return [str(word) for word in words]


def stage_inputs(scene: str, settings: Settings, sequences: list[str]) -> list[str]:
    """Every file of `stage_arguments`, each once: the solvers' timing sequence, evaluations, low-res runs, models
    and high-res runs."""
    return list(dict.fromkeys(
        solve_timing_files(scene, sequences)
        + [path for n in budgets(settings)
           for path in (*[evaluation_file(scene, n, net) for net in scene_trained_nets(settings)],
                        low_runs(scene, settings, sequences, n)[0])]
        + [path for n in matched_budgets(settings) for net in matched_nets(settings)
           for path in (evaluation_file(scene, n, net), network_model(scene, n, net))]
        + [network_model(scene, n, net) for n in budgets(settings) for net in scene_trained_nets(settings)]
        + [path for run in high_res_runs(settings) for path in high_res_files(scene, sequences, run)]
        + list(high_res_timings(scene, settings).values())))


def _with_budget(overlay: Settings, settings: Settings, name: int | str) -> Settings:
    substeps, iterations = parse_budget_name(settings, name)
    return {**overlay, "solver": {**overlay["solver"], "substeps": substeps, "iterations": iterations}}


def point_settings(settings: Settings, name: int | str) -> Settings:
    """settings.json of budget `name`: the scene's, with that low-res solver budget."""
    return _with_budget(shared_settings(settings), settings, name)


def point_simulation(settings: Settings, name: int | str) -> Settings:
    """simulation.json of budget `name`: the scene's, with that low-res solver budget."""
    return _with_budget(simulation_settings(settings), settings, name)


def network_settings(settings: Settings, width: float | str) -> Settings:
    """settings.json of the network of `width`: the scene's, with that width and the trade-off's epochs."""
    shared = shared_settings(settings)
    return {**shared, "network": {**shared["network"], "width": float(width)},
            "training": {**shared["training"], "epochs": settings["tradeoff"]["epochs"]}}


def matched_settings(settings: Settings, name: int | str, width: float | str) -> Settings:
    """settings.json of the matched network of `width` at budget `name`: the budget's, with that width (the
    scene's training recipe kept, as the matched network's)."""
    point = point_settings(settings, name)
    return {**point, "network": {**point["network"], "width": float(width)}}


def high_res_simulation(settings: Settings, run: HighResRun) -> Settings:
    """simulation.json of high-res run `run`: the scene's, with that solver budget and harmonic schedule."""
    substeps, iterations, schedule = run
    shared = simulation_settings(settings)
    return {**shared, "solver": {**shared["solver"], "substeps": int(substeps), "iterations": int(iterations)},
            "high_res": {**shared["high_res"], "harmonic_every": schedule}}
