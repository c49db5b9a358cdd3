"""The operator comparison (`results/<scene>/convs/`): the scene's network trained with each convolution (RC, EC,
SP, SPD at each filter length), architecture and seed, side by side as the paper's supplementary tables are.
`grid` plans the runs for the workflow, `stage` (`python -m experiments.convs`) gathers their evaluations into
`artifact` (convs.h5), `report` says which operator wins how often and by how much."""
