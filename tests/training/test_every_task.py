"""Every bundled task has what train, play and export need, on the CPU.

The commands themselves are task-independent and run end to end in
`test_train_play_export.py` and `test_play.py` (the tests' pendulum,
registered as a user's task). What differs per task is checked here for every registered task,
without compiling its physics (a task's Brax training and rollout programs
take minutes each to compile on a CPU):

- train: the task's training defaults are a valid config; the environment
  and networks training builds trace through the environment's reset and
  step as `ppo.train` calls them, with the observation groups the networks
  read, and the states hold the metrics the entry names;
- play: the camera that play's videos are drawn from is the entry's, a
  camera of the compiled model that sees the task's moving bodies;
- export: `mjx-composer export` writes an ONNX policy for the task's
  observation layout and action size (from freshly initialized networks
  in a run folder holding the task's defaults) that gives the JAX policy's
  actions, with the metadata a deployment reads.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer import cli
from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.host import rendering
from mjx_composer.suite.tasks import registry
from mjx_composer.training import checkpoints
from mjx_composer.training import config as config_lib
from mjx_composer.training import export as export_lib
from mjx_composer.training import policy as policy_lib
from mjx_composer.training import run_folder
from mjx_composer.training import video


@pytest.fixture(scope='module', params=registry.names())
def task(request):
  """`(name, config, env, brax_env)` as `mjx-composer train NAME` builds them."""
  config = config_lib.defaults(request.param)
  config_lib.check(config)
  env, brax_env = policy_lib.make_environment(config)
  return request.param, config, env, brax_env


def _traced_states(brax_env):
  """The state shapes after Brax's reset and one step, traced, not compiled."""
  env = brax_adapter.wrap_for_training(
      brax_env, **brax_adapter.training_kwargs(brax_env)
  )
  keys = jax.random.split(jax.random.key(0), 2)
  reset = jax.eval_shape(env.reset, jax.random.key_data(keys))
  actions = jax.ShapeDtypeStruct((2, env.action_size), jnp.float32)
  return reset, jax.eval_shape(env.step, reset, actions)


def test_training_traces_the_tasks_reset_and_step(task):
  name, config, _, brax_env = task
  reset, stepped = _traced_states(brax_env)
  entry = registry.entry(name)
  for state in (reset, stepped):
    assert set(entry.metrics) <= set(state.metrics), sorted(state.metrics)
    groups = {k: v.shape[1:] for k, v in state.obs.items()}
    assert groups == {k: tuple(v) for k, v in brax_env.observation_size.items()}
    assert state.reward.shape == state.done.shape == (2,)
  assert {policy_lib.POLICY_GROUP, config.critic_obs} <= set(stepped.obs)


def _seen_bodies(env, camera, size=(96, 128)):
  """Bodies whose geoms cover pixels of the initial state seen from `camera`."""
  model = env.mj_model
  data = mujoco.MjData(model)
  physics = env.initial_physics()
  data.qpos[:] = np.asarray(physics.data.qpos)
  mujoco.mj_forward(model, data)
  if isinstance(camera, dict):
    camera = rendering.free_camera(model, **camera)
  renderer = rendering.make_renderer(model, *size)
  try:
    renderer.enable_segmentation_rendering()
    renderer.update_scene(data, camera=camera)
    ids, types_ = np.moveaxis(renderer.render(), -1, 0)
  finally:
    renderer.close()
  geoms = ids[types_ == mujoco.mjtObj.mjOBJ_GEOM]
  bodies = model.geom_bodyid[geoms]
  return bodies[model.body_weldid[bodies] != 0]  # pixels of moving bodies


def test_videos_come_from_the_entrys_camera_which_sees_the_task(task):
  name, _, env, _ = task
  entry = registry.entry(name)
  camera = video.task_camera(name)
  if entry.camera is None:
    assert camera == video.FREE_CAMERA
  else:
    assert camera == entry.camera
    camera_id = mujoco.mj_name2id(
        env.mj_model, mujoco.mjtObj.mjOBJ_CAMERA, entry.camera
    )
    assert camera_id >= 0, f'{name}: the model has no camera {camera!r}'
  seen = _seen_bodies(env, camera)
  # The robot or the props it moves cover at least 0.5% of the image.
  assert seen.size > 0.005 * 96 * 128, (name, seen.size)


def test_export_writes_the_tasks_policy(task, tmp_path):
  import onnxruntime  # pylint: disable=g-import-not-at-top
  from brax.training.acme import running_statistics  # pylint: disable=g-import-not-at-top
  from brax.training.acme import specs  # pylint: disable=g-import-not-at-top

  name, config, _, brax_env = task
  config = config.replace(policy_layers=(8, 8), value_layers=(8,))
  obs_size = brax_env.observation_size
  networks = policy_lib.network_factory(config)(
      obs_size,
      brax_env.action_size,
      preprocess_observations_fn=running_statistics.normalize,
  )
  policy_key, value_key = jax.random.split(jax.random.key(1))
  # Observation statistics of a random batch, so that the exported
  # normalization is not the identity.
  normalizer = running_statistics.update(
      running_statistics.init_state(
          {
              k: specs.Array(tuple(v), jnp.dtype('float32'))
              for k, v in obs_size.items()
          }
      ),
      {
          k: 1.0 + 2.0 * jax.random.normal(jax.random.key(2), (5, *v))
          for k, v in obs_size.items()
      },
  )
  params = (
      normalizer,
      networks.policy_network.init(policy_key),
      networks.value_network.init(value_key),
  )
  path = str(tmp_path / name)
  run = run_folder.create(path, config)
  checkpoints.save_params(run, 8, params)
  checkpoints.finish(
      run,
      checkpoints.Checkpoint(8, 1, 8, name, obs_size, brax_env.action_size),
  )

  onnx_path = str(tmp_path / 'policy.onnx')
  assert cli.main(['export', path, '--out', onnx_path]) == 0
  meta = export_lib.read_metadata(onnx_path)
  assert meta['task'] == name
  assert meta['observation_size'] == obs_size[policy_lib.POLICY_GROUP][-1]
  checkpoint = checkpoints.latest(run)
  policy = policy_lib.make_inference(config, checkpoint)(
      checkpoint.params, deterministic=True
  )
  obs = (
      np.random.default_rng(0)
      .normal(size=(3, meta['observation_size']))
      .astype(np.float32)
  )
  want = np.asarray(policy({'policy': obs}, jax.random.PRNGKey(0))[0])
  got = onnxruntime.InferenceSession(onnx_path).run(['action'], {'obs': obs})
  np.testing.assert_allclose(got[0], want, rtol=1e-5, atol=1e-6)
  assert got[0].shape == (3, brax_env.action_size)
