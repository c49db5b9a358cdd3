"""What the operator comparison's table says, for `experiments.convs`: the rows of the paper's layout (one per task,
architecture and filter length, a column per operator), each cell's spread over the seeds, the lowest per row, which
operator wins how often and by how much, and the report's sections (report.md and report.html show the same)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy import stats

from experiments.convs.artifact import KINDS, OURS, SPLITS, Convs
from viz.html_report import Links, Paragraphs, Picture, Section, Strong, Table

PAPER_UNIT = 1e-3           # errors shown x 1e-3 scene units, as the scene's report (paper Table 3)
SPLIT_WORDS = {"train": "train", "test": "test", "heldout": "held-out"}
TASK_WORDS = {"upsampling": "Upsampling (low-res run -> high-res cloth, paper supplementary Tables 1-2)",
              "pose": "Pose to cloth (the decoder, paper supplementary Table 4)"}
# The paper's own counts (paper.txt, section 6 "Results"; its supplementary tables' numbers are not in the text).
PAPER_CLAIM = (
    "The paper's claim (section 6; the supplementary tables themselves are not reproduced in its text): over every "
    "operator at L = 9 and 13 on the pants and tank-female meshes (supplementary Table 1), RC/EC give the lowest "
    "train or test error in 34 cases and SP/SPD in 14; over architectures of about 7.8M weights with average and "
    "max pooling (Table 2), RC13/EC13 in 37 and SP13/SPD13 in 1; for the pose-to-cloth decoder on dress2 (Table 4), "
    "RC13/EC13 in 23 and SP13/SPD13 in 7.")


@dataclasses.dataclass(frozen=True)
class Row:
    """One row of the paper's layout: a task's architecture at one filter length, every operator beside."""
    task: str
    arch: str
    length: int
    params: int
    width: float
    kinds: tuple[str, ...]
    seeds: tuple[int, ...]
    values: dict[str, dict[str, np.ndarray]]     # column (l1_test, ...) -> kind -> (seeds,) values
    ms: dict[str, float]                          # kind -> median ms per frame over its seeds' evaluations
    train_seconds: dict[str, float]               # kind -> median training wall seconds over its seeds
    loop: dict[str, float]                        # column -> Loop subdivision alone's error (the same in every run)


def rows(table: Convs) -> list[Row]:
    """The rows in the order of the table's runs (task, architecture, length), the operators in KINDS order."""
    c = table.columns
    keys = list(dict.fromkeys(zip(c["task"], c["arch"], c["length"].tolist())))
    kinds = tuple(kind for kind in KINDS if kind in set(c["kind"]))
    out = []
    for task, arch, length in keys:
        here = (c["task"] == task) & (c["arch"] == arch) & (c["length"] == length)
        seeds = tuple(sorted(set(c["seed"][here].tolist())))
        order = {kind: np.flatnonzero(here & (c["kind"] == kind))[np.argsort(c["seed"][here & (c["kind"] == kind)])]
                 for kind in kinds}
        columns = [name for name in c if name[:3] in ("l1_", "l2_") and np.all(np.isfinite(c[name][here]))]
        first = np.flatnonzero(here)[0]
        out.append(Row(task, arch, int(length), int(c["params"][first]), float(c["width"][first]), kinds, seeds,
                       {name: {kind: c[name][order[kind]] for kind in kinds} for name in columns},
                       {kind: float(np.median(c["ms_inference"][order[kind]])) for kind in kinds},
                       {kind: float(np.median(c["train_seconds"][order[kind]])) for kind in kinds},
                       {name: float(c[f"loop_{name}"][first]) for name in columns}))
    return out


def lowest(row: Row, column: str) -> tuple[str, bool]:
    """The operator of lowest mean over the seeds in `column`, and whether the win is clear of the seeds' spread:
    with two seeds or more, its every seed below every seed of every other operator (the ranges do not overlap);
    with one seed no win is clear."""
    values = row.values[column]
    best = min(row.kinds, key=lambda kind: float(np.mean(values[kind])))
    clear = len(row.seeds) > 1 and all(values[best].max() < values[kind].min() for kind in row.kinds if kind != best)
    return best, clear


@dataclasses.dataclass(frozen=True)
class Wins:
    """Per operator: the cases (row x split) it has the lowest error in, and how many of those are clear."""
    cases: int
    lowest: dict[str, int]
    clear: dict[str, int]


def wins(table_rows: list[Row], term: str = "l1", task: str | None = None) -> Wins:
    """Win counts over every row (of `task`, or all) and split the rows measure, on error `term`."""
    chosen = [row for row in table_rows if task is None or row.task == task]
    kinds = chosen[0].kinds if chosen else ()
    lowest_count, clear_count, cases = dict.fromkeys(kinds, 0), dict.fromkeys(kinds, 0), 0
    for row in chosen:
        for column in (name for name in row.values if name.startswith(f"{term}_")):
            kind, clear = lowest(row, column)
            cases += 1
            lowest_count[kind] += 1
            clear_count[kind] += clear
    return Wins(cases, lowest_count, clear_count)


def margin(row: Row, column: str) -> float | None:
    """The best of SP/SPD over the best of RC/EC in `column` (their means over the seeds): above 1, RC/EC lower;
    None unless the row has operators of both families."""
    means = {kind: float(np.mean(row.values[column][kind])) for kind in row.kinds}
    ours = [v for kind, v in means.items() if kind in OURS]
    spiral = [v for kind, v in means.items() if kind not in OURS]
    if not ours or not spiral:
        return None
    return min(spiral) / max(min(ours), 1e-30)


@dataclasses.dataclass(frozen=True)
class FamilyTest:
    """RC/EC against SP/SPD paired by training: per row and seed, the best spiral operator's error over the best
    of ours (above 1: RC/EC lower), on the split a user meets (held-out where measured, else test)."""
    split: str
    ratios: np.ndarray          # (rows x seeds,) best SP/SPD over best RC/EC
    p_value: float              # Wilcoxon signed-rank on the log ratios, two-sided (1 where nothing differs)


def family_test(table_rows: list[Row], term: str = "l1", task: str | None = None) -> FamilyTest | None:
    """Whether one family is lower more consistently than the trainings' noise would make it: each (row, seed)
    is an independent training of every operator, so the sign of log(best SP/SPD / best RC/EC) over them is
    tested against a median of zero (Wilcoxon signed-rank, exact for few pairs). A row's splits are not
    independent (one network), so one split is tested. None without rows of both families."""
    chosen = [row for row in table_rows if (task is None or row.task == task)
              and any(k in OURS for k in row.kinds) and any(k not in OURS for k in row.kinds)]
    if not chosen:
        return None
    split = "heldout" if all(f"{term}_heldout" in row.values for row in chosen) else "test"
    ratios = []
    for row in chosen:
        values = row.values[f"{term}_{split}"]
        for s in range(len(row.seeds)):
            ours = min(values[k][s] for k in row.kinds if k in OURS)
            spiral = min(values[k][s] for k in row.kinds if k not in OURS)
            ratios.append(spiral / ours)
    logs = np.log(np.asarray(ratios))
    p_value = 1.0 if not np.any(logs != 0) else float(stats.wilcoxon(logs, alternative="two-sided").pvalue)
    return FamilyTest(split, np.asarray(ratios), p_value)


def _family_words(test: FamilyTest, term: str) -> str:
    median = float(np.median(test.ratios))
    if test.p_value < 0.05:
        answer = f"{'RC/EC' if median > 1 else 'SP/SPD'} lower, beyond the trainings' noise"
    else:
        answer = "neither family lower beyond the trainings' noise (p >= 0.05"
        # The exact two-sided test's smallest p with n pairs is 2 / 2^n: below 6 pairs no result reaches 0.05.
        answer += f"; with {len(test.ratios)} trainings it cannot reach 0.05)" if len(test.ratios) < 6 else ")"
    return (f" Paired by training ({len(test.ratios)}: rows x seeds) on the {SPLIT_WORDS[test.split]} "
            f"{term.upper()}: best SP/SPD over best RC/EC {median:.3f} in the median training "
            f"({test.ratios.min():.3f} to {test.ratios.max():.3f}), Wilcoxon signed-rank p = {test.p_value:.3g}: "
            f"{answer}.")


def verdict(table_rows: list[Row], term: str = "l1") -> list[str]:
    """The answer in sentences: per task, how often RC/EC and SP/SPD have the lowest error, how many of those wins
    stand clear of the seeds' spread, the ratio of the two families' best (median and range over the cases) and
    whether one family is lower beyond the trainings' noise (`family_test`)."""
    lines = []
    for task in dict.fromkeys(row.task for row in table_rows):
        count = wins(table_rows, term, task)
        ours = sum(n for kind, n in count.lowest.items() if kind in OURS)
        ours_clear = sum(n for kind, n in count.clear.items() if kind in OURS)
        spiral, spiral_clear = count.cases - ours, sum(count.clear.values()) - ours_clear
        per_kind = ", ".join(f"{kind} {n} ({count.clear[kind]} clear)" for kind, n in count.lowest.items())
        margins = [m for row in table_rows if row.task == task for column in row.values
                   if column.startswith(f"{term}_") and (m := margin(row, column)) is not None]
        seeds = max(len(row.seeds) for row in table_rows if row.task == task)
        text = (f"{TASK_WORDS[task].split(' (')[0]}: RC/EC have the lowest {term.upper()} in {ours} of {count.cases} "
                f"cases (architecture x length x split), SP/SPD in {spiral}; by operator: {per_kind}.")
        if seeds > 1:
            text += (f" Clear of the spread of {seeds} seeds (every seed of the winner below every seed of the "
                     f"others): RC/EC {ours_clear}, SP/SPD {spiral_clear}.")
        else:
            text += " One seed per run: no single win can be told from the seeds' noise (the paper profile runs 3)."
        if margins:
            text += (f" Best SP/SPD over best RC/EC (above 1: RC/EC lower): {np.median(margins):.3f} in the median "
                     f"case, {min(margins):.3f} to {max(margins):.3f}.")
        test = family_test(table_rows, term, task)
        if test is not None:
            text += _family_words(test, term)
        lines.append(text)
    return lines


def _cell(values: np.ndarray, bold: bool) -> str | Strong:
    scaled = values / PAPER_UNIT
    text = f"{scaled.mean():.3f}" + (f" ± {scaled.std(ddof=1):.3f}" if len(scaled) > 1 else "")
    return Strong(text) if bold else text


def error_table(table_rows: list[Row], task: str, term: str) -> Table:
    """The paper's layout: a row per architecture and length, per operator its train, test and held-out errors
    (mean ± standard deviation over the seeds, x 1e-3), the lowest of each split in bold."""
    chosen = [row for row in table_rows if row.task == task]
    splits = [s for s in SPLITS if f"{term}_{s}" in chosen[0].values]
    header = ["architecture", "L", "parameters",
              *[f"{kind} {SPLIT_WORDS[s]}" for kind in chosen[0].kinds for s in splits]]
    body = []
    for row in chosen:
        best = {s: lowest(row, f"{term}_{s}")[0] for s in splits}
        body.append([f"{row.arch} x{row.width:g}", row.length, f"{row.params:,}",
                     *[_cell(row.values[f"{term}_{s}"][kind], kind == best[s]) for kind in row.kinds for s in splits]])
    return Table(header, body, caption=f"{term.upper()} x 1e-3 scene units")


def win_table(table_rows: list[Row]) -> Table:
    """Per task and operator: the cases of lowest L1 and of lowest L2, and of those the clear ones."""
    body = []
    for task in dict.fromkeys(row.task for row in table_rows):
        l1, l2 = wins(table_rows, "l1", task), wins(table_rows, "l2", task)
        body += [[task, kind, f"{l1.lowest[kind]} of {l1.cases}", l1.clear[kind], f"{l2.lowest[kind]} of {l2.cases}",
                  l2.clear[kind]] for kind in l1.lowest]
    return Table(["task", "operator", "lowest L1", "clear of the seeds", "lowest L2", "clear of the seeds"], body)


def timing_table(table_rows: list[Row]) -> Table:
    """Per row and operator: the network's ms per frame and the training's wall seconds (medians over the seeds)."""
    kinds = table_rows[0].kinds
    return Table(["task", "architecture", "L", *[f"{kind} ms" for kind in kinds],
                  *[f"{kind} training s" for kind in kinds]],
                 [[row.task, f"{row.arch} x{row.width:g}", row.length, *[f"{row.ms[kind]:.3g}" for kind in kinds],
                   *[f"{row.train_seconds[kind]:.3g}" for kind in kinds]] for row in table_rows])


def sections(table: Convs, chart: Path, links: list[tuple[str, str]], recipe: str) -> list[Section]:
    table_rows = rows(table)
    out = [Section("Verdict", [Paragraphs("\n".join(f"- {line}" for line in verdict(table_rows))),
                               Paragraphs(PAPER_CLAIM)])]
    for task in dict.fromkeys(row.task for row in table_rows):
        loop = next(row for row in table_rows if row.task == task).loop
        floor = ", ".join(f"{SPLIT_WORDS[s]} {loop[f'l1_{s}'] / PAPER_UNIT:.3f}" for s in SPLITS
                          if f"l1_{s}" in loop)
        out.append(Section(TASK_WORDS[task], [
            Paragraphs("L1 (eq. 4) then L2 (eq. 5), x 1e-3 scene units: mean ± standard deviation over the seeds; "
                       f"**bold** the lowest mean of each split in its row. The predictor alone (no network) has L1 "
                       f"{floor}."),
            error_table(table_rows, task, "l1"), error_table(table_rows, task, "l2")]))
    out += [Section("Chart", [Picture(chart, "L1 per operator, mean over the seeds; bars: lowest to highest seed; "
                                             "dashed: the predictor alone.")]),
            Section("Which operator wins how often", [win_table(table_rows), Paragraphs(
                "A case is one split (train, test, held-out) of one row. Clear: with two seeds or more, every seed of "
                "the winner below every seed of every other operator, so the win is not the seeds' noise.")]),
            Section("Inference and training time", [timing_table(table_rows), Paragraphs(
                f"Median ms per frame on {table.device} on the deployment path, as each evaluation timed it, and "
                "each training's wall seconds (jobs ran beside each other; one filter length gathers as much for "
                "every operator, so at one length the operators' times differ by that noise only).")]),
            Section("How the runs were made", [Paragraphs(recipe)]),
            Section("Files", [Links(links)])]
    return out
