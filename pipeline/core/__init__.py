"""The floor that every stage (pipeline/) and experiment (experiments/) stands on: `errors` (the one exception a
CLI turns into `error: <file>: <problem>`), `h5` (safe writes, provenance attrs, checked HDF5 reads), `config`
(workflow_config.yaml and settings.json: schema, profiles, resolution), `cli` (the stages' shared command-line
plumbing), `progress` (bars), `torch_setup` (seeded, deterministic torch on one device), `meshio` (mesh files in)."""
