"""Training registered tasks from the command line: run folders and their parts.

`config` (the settings), `run_folder` and `checkpoints` (what a run folder
holds), `policy` (a run's environment and networks), `trainer` (Brax's
`ppo.train`, unchanged, and the run's metrics), `video` (a policy's
rollouts, videos and statistics: `play`) and `export` (ONNX), called by
`mjx-composer train|play|export`. A host-side layer that nothing imports
but the entry points.
"""
