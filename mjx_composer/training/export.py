"""A trained policy as an ONNX model, with what a deployment needs to know.

`export_onnx(run)` writes the newest deterministic policy, built with the
`onnx` package from the checkpoint: observation normalization (when the run
normalized), the MLP (swish activations) and the tanh of the action
distribution's mean; input `obs`, the 'policy' group `(batch, D)`, output
`action` `(batch, actions)`, float32, and its `metadata` as JSON values.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from mjx_composer.observation import updater as updater_lib
from mjx_composer.training import policy as policy_lib

FORMAT = 1
_GROUP = policy_lib.POLICY_GROUP


def metadata(env, config, checkpoint) -> dict:
  """The ONNX model's metadata: `{key: JSON-ready value}`."""
  # The 'policy' group's observables in order: the observation updater's
  # specs with the group unflattened (shapes only: nothing is computed).
  group = env.task.observation_groups()[_GROUP]
  updater = updater_lib.Updater(
      env.task.observables,
      env.n_sub_steps,
      groups={_GROUP: dataclasses.replace(group, flatten=False)},
      physics=env.initial_physics(),
  )
  spec = updater.observation_spec()[_GROUP]
  layout = [(name, tuple(int(d) for d in s.shape)) for name, s in spec.items()]
  spec = env.action_spec()
  entities = env.task.root_entity.iter_entities()
  homes = [getattr(e, 'home_joint_positions', None) for e in entities]
  homes = [np.ravel(h).astype(float).tolist() for h in homes if h is not None]
  return {
      'format': FORMAT,
      'producer': 'mjx_composer',
      'task': config.task,
      'step': int(checkpoint.step),
      'observation_group': _GROUP,
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
      'default_joint_positions': homes[0] if homes else None,
  }


def policy_graph(config, checkpoint):
  """The deterministic policy as an `onnx.ModelProto` (no metadata)."""
  import onnx  # pylint: disable=g-import-not-at-top
  from onnx import helper, numpy_helper  # pylint: disable=g-import-not-at-top,g-multiple-import

  normalizer, policy_params, _ = checkpoint.params
  layers = policy_params['params']
  names = [f'hidden_{i}' for i in range(len(config.policy_layers) + 1)]
  if sorted(layers) != sorted(names):
    raise ValueError(f'Policy parameters {list(layers)}: not the MLP exported.')
  nodes, inits = [], []

  def node(op, *inputs, consts=(), dtype=np.float32, out=None):
    """Appends `op(*inputs, *consts)` to the graph; returns its output."""
    out = out or f'{op}_{len(nodes)}'
    for i, value in enumerate(consts):
      inputs += (f'{out}/{i}',)
      array = np.asarray(value, dtype)
      inits.append(numpy_helper.from_array(array, inputs[-1]))
    nodes.append(helper.make_node(op, list(inputs), [out]))
    return out

  x = 'obs'
  if config.normalize:
    x = node('Sub', x, consts=[normalizer.mean[_GROUP]])
    x = node('Div', x, consts=[normalizer.std[_GROUP]])
  for i, name in enumerate(names):
    x = node('MatMul', x, consts=[layers[name]['kernel']])
    x = node('Add', x, consts=[layers[name]['bias']])
    if i < len(names) - 1:  # swish(x) = x * sigmoid(x)
      x = node('Mul', x, node('Sigmoid', x))
  # The distribution's parameters are [mean, scale]: the action is tanh(mean).
  actions = int(checkpoint.action_size)
  x = node('Slice', x, consts=[[0], [actions], [1]], dtype=np.int64)
  node('Tanh', x, out='action')
  size = int(checkpoint.observation_size[_GROUP][-1])
  inputs, outputs = [
      [helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, ['batch', d])]
      for n, d in (('obs', size), ('action', actions))
  ]
  graph = helper.make_graph(nodes, 'policy', inputs, outputs, inits)
  opset = [helper.make_opsetid('', 17)]
  model = helper.make_model(
      graph, producer_name='mjx_composer', opset_imports=opset
  )
  onnx.checker.check_model(model)
  return model


def export_onnx(run_path: str, out: str | None = None) -> tuple[str, dict]:
  """Writes the run's newest policy as ONNX (default: `RUN/policy.onnx`).

  Returns `(path, metadata)`; raises RunFolderError (`policy.load`).
  """
  import onnx  # pylint: disable=g-import-not-at-top

  run, config, checkpoint, env, _ = policy_lib.load(run_path)
  model = policy_graph(config, checkpoint)
  meta = metadata(env, config, checkpoint)
  for key, value in meta.items():
    model.metadata_props.add(key=key, value=json.dumps(value))
  path = out or run.join('policy.onnx')
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  onnx.save(model, path)
  return path, meta


def read_metadata(path: str) -> dict:
  """The metadata of an exported model, values decoded from JSON."""
  import onnx  # pylint: disable=g-import-not-at-top

  return {p.key: json.loads(p.value) for p in onnx.load(path).metadata_props}
