"""`python -m experiments.tradeoff`: see experiments.tradeoff.stage."""
from experiments.tradeoff.stage import main
from pipeline.core import cli

cli.run(main)
