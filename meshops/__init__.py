"""Precomputed mesh-CNN operators (Chentanez et al. 2020, sections 3.1-3.2) for any manifold triangle mesh.

`build_operators` turns a mesh into a hierarchy of levels, each with its convolution index tables (RC, EC, SP,
SPD) and the pooling/unpooling maps to the next coarser level. Plain numpy arrays in and out: this package knows
nothing of HDF5 layouts, the pipeline or torch.
"""
from meshops.levels import Level, build_operators, parse_conv_kind, parse_conv_kinds

__all__ = ["Level", "build_operators", "parse_conv_kind", "parse_conv_kinds"]
