"""Training registered tasks from the command line: run folders and their parts.

One concept per module: `config` (the settings, per-task defaults, files
and flags), `run_folder` (what a run folder holds), `checkpoints` (the
latest and the best parameters, resumed through Brax's `restore_params`),
`metrics` (CSV, TensorBoard, Weights & Biases), `video` (rendered rollouts
as MP4), `policy` (the environment and networks of a run), `trainer`
(Brax's `ppo.train`, unchanged, filling the run folder), `play` (a trained
policy's videos and episode statistics) and `export` (the policy as ONNX).
The `mjx-composer train|play|export` commands (`mjx_composer.cli`) call
them. This is a host-side layer: it imports the environment, the Brax
adapter, host rendering and the task registry, and nothing imports it but
the entry points.
"""
