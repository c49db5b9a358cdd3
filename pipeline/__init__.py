"""Thin glue between the libraries (`sim`, `meshops`, `model`) and Snakemake: one module per stage.

Each stage module has a small CLI (`python -m pipeline.<stage> ...`) that reads its input artifacts, calls a
library, and writes its output artifact atomically through `pipeline.artifacts`.
"""
