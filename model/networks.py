"""The paper's networks: the encoder-decoder with skips (Fig. 6) and the decoder (Fig. 7).

Each network compiles its architecture into a flat list of `Step`s once; `forward` runs that list and
`model.summary` prints it, so the layer table always describes exactly what runs. The wiring (which features
are skipped, where the output head sits) is the one that reproduces the paper's Table 3 parameter counts; see
docs/architecture.md ("Network architecture grammar") for the derivation.
"""
from __future__ import annotations

import dataclasses

import torch
from torch import nn

from model.architecture import Architecture, ArchitectureError, parse_architecture, parse_conv
from model.mesh_hierarchy import MeshHierarchy
from model.layers import POOLING, MeshConv, instance_norm, leaky_relu, unpool


@dataclasses.dataclass(frozen=True)
class Step:
    """One operation: `op` in conv | norm | save | pool | unpool | concat | linear; `level` the mesh level it
    reads (for unpool: the fine level it writes); `index` the conv's position in `convs`; `block` a label."""

    op: str
    level: int
    block: str
    index: int = -1


class MeshNetwork(nn.Module):
    """Shared machinery: a step list over `self.convs`, and the checks a mesh must pass before a forward."""

    kind = ""
    n_levels = 0

    def __init__(self, pool: str | None):
        super().__init__()
        if pool is not None and pool not in POOLING:
            raise ArchitectureError(f"pooling must be one of {sorted(POOLING)}, got '{pool}'")
        self.pool_kind = pool
        self.convs = nn.ModuleList()
        self.steps: list[Step] = []

    def _conv(self, in_channels: int, out_channels: int, size: int, level: int, block: str) -> None:
        self.steps.append(Step("conv", level, block, len(self.convs)))
        self.convs.append(MeshConv(in_channels, out_channels, size))

    def _up_block(self, channels: int, h: int | None, conv_size: int, level: int, skip: bool, norm: bool) -> int:
        """Fig. 5's UpConv from `level` to `level - 1` (conv → unpool → [concat skip] → conv → [IN → leaky
        ReLU]), or a plain unpooling when `h` is None; returns the channel count after it."""
        name = f"U^{h}" if h is not None else "U"
        if h is not None:
            self._conv(channels, h, conv_size, level, name)
        self.steps.append(Step("unpool", level - 1, name))
        if h is None:
            return channels
        if skip:
            self.steps.append(Step("concat", level - 1, name))
        self._conv(2 * h if skip else h, h, conv_size, level - 1, name)
        if norm:
            self.steps.append(Step("norm", level - 1, name))
        return h

    def check_mesh(self, mesh: MeshHierarchy) -> None:
        if mesh.n_levels < self.n_levels:
            raise ValueError(f"the {self.kind} needs {self.n_levels} mesh levels ({self.n_levels - 1} poolings) "
                             f"but the operators provide {mesh.n_levels}")
        if mesh.conv_size != self.convs[0].size:
            raise ValueError(f"the network was built for convolutions of size {self.convs[0].size}, "
                             f"the operators have size {mesh.conv_size}")

    def _run(self, x: torch.Tensor, mesh: MeshHierarchy) -> torch.Tensor:
        self.check_mesh(mesh)
        skips: list[torch.Tensor] = []
        for step in self.steps:
            if step.op == "linear":
                x = self.linear(x).reshape(x.shape[0], self.coarse_vertices, self.coarse_channels)
            elif step.op == "conv":
                x = self.convs[step.index](x, mesh.conv[step.level])
            elif step.op == "norm":
                x = leaky_relu(instance_norm(x))
            elif step.op == "save":
                skips.append(x)
            elif step.op == "pool":
                x = POOLING[self.pool_kind](x, mesh.pool[step.level])
            elif step.op == "unpool":
                x = unpool(x, mesh.unpool[step.level])
            elif step.op == "concat":
                x = torch.cat([x, skips.pop()], dim=-1)
        return x

    def parameter_count(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)


class EncoderDecoder(MeshNetwork):
    """Fig. 6: DownConv blocks down to the coarsest level, UpConv blocks back up with skips, then two convs.

    DownConv = conv → IN → leaky ReLU → pool, its pre-pool features kept as the skip. The deepest DownConv is the
    bottleneck and does not pool (its pooled features would only be unpooled again). Mirroring every block but
    the deepest, from coarse to fine: a plain pooling becomes an unpooling, and D^h at level l becomes the UpConv
    U^h landing on level l: conv (to h) → unpool → concatenate the skip of D^h → conv (2h to h) → IN → leaky ReLU.
    The output head, on the input mesh, is conv (to out) → conv (out to out) with neither normalisation nor
    activation, since the output is a regression target.
    """

    kind = "encoder-decoder"

    def __init__(self, arch: Architecture, conv_size: int, pool: str = "avg", in_channels: int = 3,
                 out_channels: int = 3):
        super().__init__(pool)
        if arch.letter != "D":
            raise ArchitectureError(f"an encoder-decoder is written with D tokens, got '{arch}'")
        if arch.blocks[-1] is None:
            raise ArchitectureError(f"'{arch}' ends with a plain pooling: the deepest block must be a DownConv "
                                    f"D^h (a pooling there would only be undone by the decoder)")
        self.arch, self.in_channels, self.out_channels = arch, in_channels, out_channels
        self.n_levels = len(arch.blocks)          # the deepest block does not pool
        channels, level = in_channels, 0
        deepest = len(arch.blocks) - 1
        for i, h in enumerate(arch.blocks):
            name = f"D^{h}" if h is not None else "D"
            if h is not None:
                self._conv(channels, h, conv_size, level, name)
                self.steps.append(Step("norm", level, name))
                channels = h
                if i == deepest:
                    break
                self.steps.append(Step("save", level, name))
            self.steps.append(Step("pool", level, name))
            level += 1
        for h in reversed(arch.blocks[:-1]):
            channels = self._up_block(channels, h, conv_size, level, skip=True, norm=True)
            level -= 1
        self._conv(channels, out_channels, conv_size, 0, "head")
        self._conv(out_channels, out_channels, conv_size, 0, "head")

    def forward(self, x: torch.Tensor, mesh: MeshHierarchy) -> torch.Tensor:
        """x (B, V_0, in_channels) → (B, V_0, out_channels)."""
        return self._run(x, mesh)


class Decoder(MeshNetwork):
    """Fig. 7: a fully connected layer → IN → leaky ReLU to features on the coarsest level, then UpConv blocks
    without skips (conv → unpool → conv → IN → leaky ReLU) or plain unpoolings, one level each.

    The last block must be an UpConv with the output's channel count; it is the output layer, so it skips the
    normalisation and activation.
    """

    kind = "decoder"

    def __init__(self, arch: Architecture, conv_size: int, n_inputs: int, coarse_vertices: int,
                 out_channels: int = 3):
        super().__init__(None)
        if arch.letter != "U":
            raise ArchitectureError(f"a decoder is written with U tokens, got '{arch}'")
        if arch.blocks[-1] != out_channels:
            raise ArchitectureError(f"'{arch}' must end with the output block U^{out_channels}")
        self.arch, self.n_inputs, self.out_channels = arch, n_inputs, out_channels
        self.coarse_vertices = coarse_vertices
        self.n_levels = len(arch.blocks) + 1
        channels = next(h for h in arch.blocks if h is not None)
        self.linear = nn.Linear(n_inputs, coarse_vertices * channels)
        self.coarse_channels = channels
        level = len(arch.blocks)
        self.steps.append(Step("linear", level, "FC"))
        self.steps.append(Step("norm", level, "FC"))
        for i, h in enumerate(arch.blocks):
            channels = self._up_block(channels, h, conv_size, level, skip=False, norm=i < len(arch.blocks) - 1)
            level -= 1

    def check_mesh(self, mesh: MeshHierarchy) -> None:
        super().check_mesh(mesh)
        coarse = mesh.vertex_counts[self.n_levels - 1]
        if coarse != self.coarse_vertices:
            raise ValueError(f"the decoder was built for {self.coarse_vertices} vertices on its coarsest level "
                             f"({self.n_levels - 1}), the operators have {coarse}")

    def forward(self, z: torch.Tensor, mesh: MeshHierarchy) -> torch.Tensor:
        """z (B, n_inputs) → (B, V_0, out_channels)."""
        return self._run(z, mesh)


@dataclasses.dataclass(frozen=True)
class NetworkSpec:
    """Everything needed to rebuild a network (stored in model.pt). The architecture's letter picks the network:
    D tokens an encoder-decoder on `in_channels` per-vertex inputs, U tokens a decoder from `in_channels` scalars,
    which also needs the vertex count of its coarsest level."""

    arch: str
    conv: str = "RC13"
    pool: str = "avg"
    width: float = 1.0
    in_channels: int = 3
    out_channels: int = 3
    coarse_vertices: int | None = None

    @property
    def letter(self) -> str:
        return self.arch.strip()[:1]


def build_network(spec: NetworkSpec) -> MeshNetwork:
    """The network a spec describes; raises ArchitectureError naming what is wrong with it."""
    _, size = parse_conv(spec.conv)
    if spec.letter == "U":
        arch = parse_architecture(spec.arch, "U").scaled(spec.width, keep_last=True)
        if spec.coarse_vertices is None:
            raise ArchitectureError("a decoder needs the vertex count of its coarsest mesh level")
        return Decoder(arch, size, spec.in_channels, spec.coarse_vertices, spec.out_channels)
    arch = parse_architecture(spec.arch, "D").scaled(spec.width)
    return EncoderDecoder(arch, size, spec.pool, spec.in_channels, spec.out_channels)
