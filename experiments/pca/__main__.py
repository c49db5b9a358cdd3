"""`python -m experiments.pca`: see experiments.pca.stage."""
from experiments.pca.stage import main
from pipeline.core import cli

cli.run(main)
