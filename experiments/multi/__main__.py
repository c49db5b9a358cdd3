"""`python -m experiments.multi`: see experiments.multi.stage."""
from experiments.multi.stage import main
from pipeline.core import cli

cli.run(main)
