"""Shared command-line plumbing for the stage modules."""
from __future__ import annotations

import argparse
import itertools
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TypeVar

from pipeline.core.config import load_settings, require_complete_settings
from pipeline.core.errors import PipelineError
from pipeline.core.gpu_slots import claim_gpu

T = TypeVar("T")


def run(main: Callable[[Sequence[str] | None], None], argv: Sequence[str] | None = None) -> None:
    """Run a stage's `main`, turning `PipelineError` into `error: ...` on stderr and exit status 2."""
    exit_on_error(main, argv)


def exit_on_error(work: Callable[..., T], *args: Any) -> T:
    """`work(*args)`, a PipelineError becoming `error: ...` on stderr and exit status 2: for the stages, and for
    the Snakefile, where Snakemake would follow the line with a stack of Snakefile frames."""
    try:
        return work(*args)
    except PipelineError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def add_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=int, help="CPU threads for torch (Snakemake: the rule's threads)")


def parse_with_settings(parser: argparse.ArgumentParser, argv: Sequence[str] | None,
                        flags_of: Callable[[dict], dict[str, Any]], unread: tuple[str, ...] = ()) -> argparse.Namespace:
    """Parse a stage's arguments, taking the defaults of its flags from `--settings SETTINGS.json`.

    The resolved scene settings (written by `python -m pipeline.settings`) are read first; `flags_of(settings)`
    maps them to flag destinations, and those values become the flags' defaults, so a flag given by hand still
    wins (a variant tried without editing the config). Each value is handed to argparse as the text the flag
    would get on a command line (a list comma-joined; None leaves the flag without a value), which argparse
    converts with the flag's own `type`: a setting and the same value typed by hand give the same argument.
    (argparse does not check `choices` on defaults; the config schema has checked those values, as
    `pipeline.core.config.read_settings` does, naming first a missing setting this stage reads.) `settings` is kept out
    of the returned namespace, so an artifact's recorded config holds the flags' values only. The top-level
    settings `unread` (never used by this stage) may be absent, as in simulation.json.
    """
    parser.add_argument("--settings", metavar="SETTINGS.json",
                        help="resolved scene settings (python -m pipeline.settings): the defaults of the flags")
    settings_path = settings_of(argv)
    if settings_path is not None:
        settings = load_settings(settings_path)
        try:
            defaults = flags_of(settings)
        except KeyError as err:
            raise PipelineError(f"{settings_path}: missing setting {err}") from None
        require_complete_settings(settings, settings_path, unread)
        parser.set_defaults(**{dest: _as_flag_text(value) for dest, value in defaults.items()})
    args = parser.parse_args(argv)
    del args.settings
    return args


def boolean(text: str) -> bool:
    """A flag's true/false value, as a setting (True/False) or a person (true, false, yes, no, on, off, 1, 0)
    spells it."""
    words = {"true": True, "yes": True, "on": True, "1": True, "false": False, "no": False, "off": False, "0": False}
    if text.lower() not in words:
        raise argparse.ArgumentTypeError(f"'{text}' is not true or false")
    return words[text.lower()]


def settings_of(argv: Sequence[str] | None) -> str | None:
    """The `--settings` path of a command line (None without one); `parse_with_settings` keeps it out of the
    namespace it returns."""
    given = argparse.ArgumentParser(add_help=False)
    given.add_argument("--settings")
    return given.parse_known_args(argv)[0].settings


def check_device(device: str, library: str, cuda_count: Callable[[], int], whole_gpu: bool = False) -> None:
    """Refuse a device that is not `cpu`, `cuda` or `cuda:N`, or a CUDA device beyond the `cuda_count()` that
    `library` (torch, Warp) sees, before the library itself fails on it with a traceback. A CUDA device of a job
    that shares several GPUs with others is the free one it takes first (pipeline.core.gpu_slots; `whole_gpu`:
    with none of its slots held by another job), before the library reads which GPUs it may see."""
    match = re.fullmatch(r"cpu|cuda(?::([0-9]+))?", device)
    if match is None:
        raise PipelineError(f"device '{device}' is not cpu, cuda or cuda:N (--device)")
    if device != "cpu":
        claim_gpu(whole=whole_gpu)
        count = cuda_count()
        if int(match[1] or 0) >= count:
            raise PipelineError(f"device '{device}' requested but {library} finds {count} CUDA device(s) "
                                f"(--device {'cpu' if count == 0 else f'cuda:0 .. cuda:{count - 1}'})")


def refuse_aliases(outputs: Mapping[str, str | os.PathLike], inputs: Mapping[str, str | os.PathLike | None]) -> None:
    """Refuse, before anything is written, an output that is the same file as another output or an input (say
    a checkpoint path equal to the dataset: it would be overwritten, then deleted). Paths are compared resolved
    (symlinks followed) and, for existing files, by inode (hard links). Keys name the roles in the message."""
    roles = {**{role: path for role, path in inputs.items() if path is not None}, **outputs}
    for (role_a, a), (role_b, b) in itertools.combinations(roles.items(), 2):
        if (role_a in outputs or role_b in outputs) and _same_file(a, b):
            raise PipelineError(f"{a}: {role_a} and {role_b} are the same file; give each its own path")


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    if Path(a).resolve() == Path(b).resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:      # one of them does not exist (yet): only the resolved paths could coincide
        return False


def _as_flag_text(value: Any) -> str | None:
    """A setting as the text of its command-line flag, the way a shell command spells it."""
    if value is None:
        return None
    if isinstance(value, (list, tuple)):
        return ",".join(map(str, value))
    return str(value)
