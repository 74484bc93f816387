"""Deployment: export a trained actor for a robot (`fedjax-nav export`, docs/export.md).

`fedjax_nav.deploy.export.export_run` writes a folder usable without JAX: numpy weights + a copy
of `policy_template.py` (the actor in numpy) and `policy_inputs.py` (the observation functions),
or an ONNX graph; `add_parser` / `run_cli` are the `export` command. Nothing is imported here, so that
`python -m fedjax_nav.deploy.export` runs cleanly and importing the package costs nothing.
"""
