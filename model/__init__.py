"""The learning library: mesh operator tables → torch layers, the paper's networks, and their losses.

It sees arrays and index tables only: it knows nothing of Snakemake, HDF5 layouts or how the data was simulated.
Features are laid out channels-last, (batch, vertices, channels), so that a mesh convolution is one gather
followed by one dense matrix product.
"""
