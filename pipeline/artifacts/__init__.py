"""The artifacts the stage chain exchanges: each module is the one typed reader/writer of one artifact, where its
dataset names are defined (the HDF5 primitives they share: pipeline.core.h5)."""
