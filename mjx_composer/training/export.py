"""A trained policy as an ONNX model, with what a deployment needs to know.

`export_onnx(run)` writes the run's newest deterministic policy as an ONNX
graph built with the `onnx` package from the checkpoint's parameters:
Brax's PPO policy is observation normalization (when the run normalized),
an MLP of dense layers with swish activations, and the tanh of the action
distribution's mean. Input `obs`: the 'policy' observation group, float32
`(batch, D)`; output `action`: float32 `(batch, actions)` in [-1, 1], the
environment's action.

The model's metadata (`metadata_props`, each value JSON) says how to feed
and read it: the observation group's observables in order with their
shapes, the action bounds and how actions map onto them, the control
timestep, the robot's default joint positions where it has them
(`home_joint_positions`), the task, the step trained and the exporter's
format version.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from mjx_composer.observation import updater as updater_lib
from mjx_composer.training import checkpoints
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder

FORMAT = 1


def observation_layout(env, group: str = policy_lib.POLICY_GROUP):
  """`[(observable name, shape)]` of a flat observation group, in order.

  Rebuilds the environment's observation updater with the group unflattened
  (observation shapes only: nothing is computed) and reads its specs.

  Raises:
    ValueError: if the task has no such group, or the layout does not add
      up to the group's size.
  """
  task = env.task
  task_groups = task.observation_groups() or {}
  if group not in task_groups:
    raise ValueError(
        f'Task {type(task).__name__} has no observation group {group!r} '
        f'(it has {sorted(task_groups)}).'
    )
  unflat = {group: dataclasses.replace(task_groups[group], flatten=False)}
  updater = updater_lib.Updater(
      task.observables,
      env.n_sub_steps,
      groups=unflat,
      physics=env.initial_physics(),
  )
  spec = updater.observation_spec()[group]
  layout = [(name, tuple(int(d) for d in s.shape)) for name, s in spec.items()]
  size = sum(int(np.prod(shape)) for _, shape in layout)
  want = env.observation_spec()[group].shape[-1]
  if size != want:
    raise ValueError(
        f'The observation group {group!r} has {want} values, its observables '
        f'{size}: the environment was built with other groups than the '
        "task's."
    )
  return layout


def _default_joint_positions(env):
  for entity in env.task.root_entity.iter_entities():
    home = getattr(entity, 'home_joint_positions', None)
    if home is not None:
      return [float(x) for x in np.asarray(home).ravel()]
  return None


def metadata(env, config, checkpoint) -> dict:
  """The ONNX model's metadata: `{key: JSON-ready value}`."""
  spec = env.action_spec()
  layout = observation_layout(env)
  return {
      'format': FORMAT,
      'producer': 'mjx_composer',
      'task': config.task,
      'step': int(checkpoint.step),
      'observation_group': policy_lib.POLICY_GROUP,
      'observation_names': [name for name, _ in layout],
      'observation_shapes': [list(shape) for _, shape in layout],
      'observation_size': int(sum(np.prod(s) for _, s in layout)),
      'observation_normalized_inside': bool(config.normalize),
      'action_size': int(checkpoint.action_size),
      'action_minimum': np.broadcast_to(spec.minimum, spec.shape).tolist(),
      'action_maximum': np.broadcast_to(spec.maximum, spec.shape).tolist(),
      'action_transform': (
          "tanh of the policy's mean, in [-1, 1]; passed to the "
          "environment's step as it is (no rescaling)"
      ),
      'control_timestep': float(env.control_timestep()),
      'default_joint_positions': _default_joint_positions(env),
  }


def policy_graph(config, checkpoint):
  """The deterministic policy as an `onnx.ModelProto` (no metadata)."""
  import onnx  # pylint: disable=g-import-not-at-top
  from onnx import helper  # pylint: disable=g-import-not-at-top
  from onnx import numpy_helper  # pylint: disable=g-import-not-at-top

  normalizer, policy_params, _ = checkpoint.params
  layers = policy_params['params']
  names = sorted(layers, key=lambda n: int(n.split('_')[-1]))
  if (
      names != [f'hidden_{i}' for i in range(len(names))]
      or len(names) != len(config.policy_layers) + 1
  ):
    raise ValueError(
        f'The policy parameters ({list(layers)}) are not the MLP that '
        f'policy_layers={config.policy_layers} gives: cannot export.'
    )
  size = int(checkpoint.observation_size[policy_lib.POLICY_GROUP][-1])
  actions = int(checkpoint.action_size)
  nodes, inits = [], []

  def const(name, value):
    inits.append(numpy_helper.from_array(np.asarray(value, np.float32), name))
    return name

  x = 'obs'
  if config.normalize:
    mean = np.asarray(normalizer.mean[policy_lib.POLICY_GROUP])
    std = np.asarray(normalizer.std[policy_lib.POLICY_GROUP])
    nodes.append(helper.make_node('Sub', [x, const('obs_mean', mean)], ['c']))
    nodes.append(
        helper.make_node('Div', ['c', const('obs_std', std)], ['normalized'])
    )
    x = 'normalized'
  for i, name in enumerate(names):
    kernel = const(f'{name}/kernel', layers[name]['kernel'])
    bias = const(f'{name}/bias', layers[name]['bias'])
    nodes.append(helper.make_node('MatMul', [x, kernel], [f'{name}/mm']))
    nodes.append(helper.make_node('Add', [f'{name}/mm', bias], [f'{name}/out']))
    x = f'{name}/out'
    if i < len(names) - 1:  # swish(x) = x * sigmoid(x)
      nodes.append(helper.make_node('Sigmoid', [x], [f'{name}/sig']))
      nodes.append(helper.make_node('Mul', [x, f'{name}/sig'], [f'{name}/act']))
      x = f'{name}/act'
  # The distribution's parameters are [mean, scale]: the action is tanh(mean).
  nodes.append(
      helper.make_node(
          'Slice',
          [
              x,
              const_int(inits, 'starts', [0]),
              const_int(inits, 'ends', [actions]),
              const_int(inits, 'axes', [1]),
          ],
          ['mean'],
      )
  )
  nodes.append(helper.make_node('Tanh', ['mean'], ['action']))
  graph = helper.make_graph(
      nodes,
      'policy',
      [
          helper.make_tensor_value_info(
              'obs', onnx.TensorProto.FLOAT, ['batch', size]
          )
      ],
      [
          helper.make_tensor_value_info(
              'action', onnx.TensorProto.FLOAT, ['batch', actions]
          )
      ],
      initializer=inits,
  )
  model = helper.make_model(
      graph,
      producer_name='mjx_composer',
      opset_imports=[helper.make_opsetid('', 17)],
  )
  onnx.checker.check_model(model)
  return model


def const_int(inits, name, values):
  from onnx import numpy_helper  # pylint: disable=g-import-not-at-top

  inits.append(numpy_helper.from_array(np.asarray(values, np.int64), name))
  return name


def export_onnx(run_path: str, out: str | None = None) -> tuple[str, dict]:
  """Writes the run's newest policy as ONNX; returns `(path, metadata)`.

  Args:
    run_path: the run folder.
    out: the file to write (default: `RUN/policy.onnx`).

  Raises:
    RunFolderError: for a missing or corrupted run folder or checkpoint.
    ImportError: without the `onnx` package (the `train` extra).
  """
  try:
    import onnx  # pylint: disable=g-import-not-at-top
  except ImportError as e:
    raise ImportError(
        "ONNX export needs onnx: pip install 'mjx-composer[train]'."
    ) from e
  run = run_folder.open_run(run_path)
  config = run.read_config()
  checkpoint = checkpoints.latest(run)
  env, brax_env = policy_lib.make_environment(config)
  checkpoints.check_compatible(
      checkpoint, config.task, brax_env.observation_size, brax_env.action_size
  )
  model = policy_graph(config, checkpoint)
  meta = metadata(env, config, checkpoint)
  for key, value in meta.items():
    entry = model.metadata_props.add()
    entry.key, entry.value = key, json.dumps(value)
  path = out or run.join('policy.onnx')
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  onnx.save(model, path)
  return path, meta


def read_metadata(path: str) -> dict:
  """The metadata of an exported model, values decoded from JSON."""
  import onnx  # pylint: disable=g-import-not-at-top

  model = onnx.load(path)
  return {p.key: json.loads(p.value) for p in model.metadata_props}
