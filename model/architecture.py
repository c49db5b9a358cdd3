"""The architecture grammar: the paper's D^h_k / U^h_k notation as a config string.

docs/architecture.md, section "Network architecture grammar", derives the paper's parameter counts from it.

A string is whitespace-separated tokens, all D (encoder-decoder networks) or all U (decoder networks):

    D^h_k   k DownConv blocks with h output channels      (also written Dh_k, D^{h}_{k}; k = 1 if absent)
    D_k     k plain poolings                                (D alone: one)
    U^h_k   k UpConv blocks with h output channels; U_k / U: k / one plain unpooling

A bare number after the letter is the channel count, as in the paper's decoder string U208 ... U3: write the
paper's D_3 (three poolings) with its underscore, `D62 D124 D248 D D248 D_3 D248`.
"""
from __future__ import annotations

import dataclasses
import math
import re

_TOKEN = re.compile(r"^(?P<letter>[DU])(?:\^?\{?(?P<channels>\d+)\}?)?(?:_\{?(?P<repeat>\d+)\}?)?$")


class ArchitectureError(ValueError):
    """An architecture string that cannot be parsed or cannot be built; the message names the token."""


@dataclasses.dataclass(frozen=True)
class Architecture:
    """A parsed architecture: `letter` 'D' or 'U', and one entry per block, the channel count or None for a
    plain pooling/unpooling, in order."""

    letter: str
    blocks: tuple[int | None, ...]

    def __str__(self) -> str:
        """The canonical expanded form, e.g. 'D^62 D^124 D D D'."""
        return " ".join(self.letter if h is None else f"{self.letter}^{h}" for h in self.blocks)

    @property
    def n_pooling(self) -> int:
        return len(self.blocks)

    def scaled(self, width: float, keep_last: bool = False) -> Architecture:
        """Every channel count times `width`, rounded up to an even count (the rounding that reproduces the
        paper's x/2 and x/4 parameter counts); `keep_last` leaves the final block (an output layer) alone."""
        if not width > 0:
            raise ArchitectureError(f"width multiplier must be > 0, got {width}")
        if width == 1:
            return self
        last = len(self.blocks) - 1
        blocks = tuple(h if h is None or (keep_last and i == last) else max(2, 2 * math.ceil(h * width / 2 - 1e-9))
                       for i, h in enumerate(self.blocks))
        return Architecture(self.letter, blocks)


def parse_architecture(text: str, letter: str) -> Architecture:
    """Parse an architecture string whose tokens must all use `letter` ('D' or 'U')."""
    tokens = text.split()
    if not tokens:
        raise ArchitectureError("architecture string is empty")
    blocks: list[int | None] = []
    for position, token in enumerate(tokens, start=1):
        match = _TOKEN.match(token)
        if match is None:
            raise ArchitectureError(f"token {position} '{token}' of '{text}' is not of the form "
                                    f"{letter}, {letter}^h, {letter}_k or {letter}^h_k")
        if match["letter"] != letter:
            raise ArchitectureError(f"token {position} '{token}' of '{text}': this network takes {letter} tokens "
                                    f"only ({'DownConv/pooling' if letter == 'D' else 'UpConv/unpooling'})")
        channels = int(match["channels"]) if match["channels"] is not None else None
        repeat = int(match["repeat"]) if match["repeat"] is not None else 1
        if channels == 0 or repeat == 0:
            raise ArchitectureError(f"token {position} '{token}' of '{text}': channel and repeat counts must be >= 1")
        blocks.extend([channels] * repeat)
    return Architecture(letter, tuple(blocks))


CONV_KINDS = ("RC", "EC", "SP", "SPD")
_CONV = re.compile(r"^(?P<kind>RC|EC|SPD|SP)(?P<size>\d+)$")


def parse_conv(name: str) -> tuple[str, int]:
    """'RC13' → ('RC', 13): the operator kind (RC, EC, SP, SPD) and filter length L (the vertex included)."""
    match = _CONV.match(name)
    if match is None or int(match["size"]) < 1:
        raise ArchitectureError(f"convolution '{name}' is not one of {', '.join(CONV_KINDS)} followed by a "
                                f"filter size, e.g. RC13 or SP9")
    return match["kind"], int(match["size"])
