"""One network for several garments (`results/multi/`): `garments` checks and plans the scenes for the workflow,
`stage` (`python -m experiments.multi train|view`) trains the shared network and writes each garment's view,
`model_file` is its model.pt, `report` (`python -m experiments.multi.report`) compares it with each garment's own
network in `table` (multi.h5)."""
