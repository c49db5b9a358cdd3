"""The stage chain, one module per stage, each a small CLI (`python -m pipeline.<stage> ...`) that reads its input
artifacts, calls a library (`scenes`, `sim`, `meshops`, `model`, `viz`) and writes its output artifact
atomically: settings → scene → subdivide → simulate → operators → dataset → train → evaluate (→ export_model).

Beneath the stages: `pipeline.core` (the floor every stage and experiment stands on: errors, safe writes and
checked HDF5 reads, settings, the CLI layer, torch setup, mesh files), `pipeline.artifacts` (one typed
reader/writer per artifact of the chain) and `pipeline.tasks` (the learning problems: what a network reads,
predicts and is timed and reported by). The experiment families over the chain live in `experiments/`.
"""
