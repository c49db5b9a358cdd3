"""The PCA details-recovery family (`results/<scene>/pca/`): one decoder per component count K of the pca task
(pipeline/tasks/pca.py), each trained and evaluated by the stage chain; `stage` (`python -m experiments.pca`)
tabulates how much of the truncation error each recovers."""
