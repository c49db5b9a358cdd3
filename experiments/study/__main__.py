"""`python -m experiments.study`: see experiments.study.stage."""
from experiments.study.stage import main
from pipeline.core import cli

cli.run(main)
