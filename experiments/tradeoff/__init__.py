"""The speed-accuracy trade (`results/<scene>/tradeoff/`): every way to the high-res cloth, error against ms per
frame. `grid` plans the budgets, networks and high-res runs for the workflow, `stage` (`python -m
experiments.tradeoff`) scores and times them into `artifact` (tradeoff.h5), `report` says what the table shows."""
