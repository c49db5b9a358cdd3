"""The generalisation study (`results/<scene>/study/`): one network per number of training sequences and input
variant, its held-out error against the amount of motion. `points` plans the grid for the workflow, `stage`
(`python -m experiments.study`) writes study.h5, the plot and the report from the grid's evaluations."""
