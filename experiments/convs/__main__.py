"""`python -m experiments.convs`: see experiments.convs.stage."""
from experiments.convs.stage import main
from pipeline.core import cli

cli.run(main)
