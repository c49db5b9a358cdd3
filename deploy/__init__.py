"""Deployment: a trained upsampler as a self-contained torch.export program (`export.py`), and the standalone
script that runs it with torch and numpy alone (`runner.py`, copied into every export). deploy/README.md says how
to run it; docs/artifacts.md lists the files."""
