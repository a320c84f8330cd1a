"""The corridor port (`examples/ports/corridor`) against dm_control's own task.

`RunThroughCorridor` with the `Ant` in an `EmptyCorridor`, ported with its
imports changed and its hooks made pure, runs batched; on the same state
(qpos, qvel and ctrl set alike) its observations, reward and termination equal
those of dm_control's task (MuJoCo's C library on the host) to float32
rounding. The egocentric camera is off on both sides (MJX ray-casts images;
dm_control renders them with OpenGL).
"""

from dm_control import composer as dm_composer
from dm_control.locomotion.arenas import corridors as dm_arenas
from dm_control.locomotion.tasks import corridors as dm_tasks
from dm_control.locomotion.walkers import ant as dm_ant
from dm_control.mujoco.wrapper.mjbindings import mjlib
import jax
import numpy as np
import pytest

import mjx_composer as composer

# examples/ports/corridor/
from corridor.arenas import corridors as port_arenas
from corridor.tasks import corridors as port_tasks
from corridor.walkers import ant as port_ant

_BATCH = 2
_STEPS = 3


def _task(arenas, tasks, ant):
  walker = ant.Ant()
  task = tasks.RunThroughCorridor(walker=walker, arena=arenas.EmptyCorridor())
  walker.observables.egocentric_camera.enabled = False
  return task


@pytest.fixture(scope='module')
def port():
  """The port's environment, reset and stepped batched with random actions."""
  task = _task(port_arenas, port_tasks, port_ant)
  env = composer.Environment(task, time_limit=10.0)
  reset = jax.jit(jax.vmap(env.reset))
  step = jax.jit(jax.vmap(env.step))
  spec = env.action_spec()
  actions = (
      np.random.RandomState(0)
      .uniform(spec.minimum, spec.maximum, (_STEPS, _BATCH) + spec.shape)
      .astype(np.float32)
  )
  states = [reset(jax.random.split(jax.random.key(0), _BATCH))]
  for action in actions:
    states.append(step(states[-1], action))
  return env, task, states


@pytest.fixture(scope='module')
def reference():
  """dm_control's own task, environment and physics."""
  task = _task(dm_arenas, dm_tasks, dm_ant)
  env = dm_composer.Environment(task, time_limit=10.0, random_state=0)
  env.reset()
  # composer's arena asks for 5 noslip iterations, which MJX does not run
  # (the port's arena leaves them out): the reference runs without them.
  env.physics.model.opt.noslip_iterations = 0
  return env, task


def _enabled(task):
  return {k: o for k, o in task.observables.items() if o.enabled}


def test_both_run_batched(port, reference):
  env, task, states = port
  for state in states[1:]:
    assert np.asarray(state.reward).shape == (_BATCH,)
    assert np.all(np.isfinite(np.asarray(state.reward)))
  assert np.all(np.asarray(states[-1].data.time) > 0)
  # The worlds moved apart (different keys, different actions).
  qpos = np.asarray(states[-1].data.qpos)
  assert not np.allclose(qpos[0], qpos[1])
  dm_env, dm_task = reference
  for _ in range(_STEPS):
    timestep = dm_env.step(np.zeros(dm_env.action_spec().shape))
    assert np.isfinite(timestep.reward)
  assert set(_enabled(task)) == set(_enabled(dm_task))
  assert set(states[-1].observation) == set(timestep.observation)


def test_the_compiled_models_agree(port, reference):
  mine = port[0].mj_model
  theirs = reference[0].physics.model.ptr
  for size in ('nq', 'nv', 'nu', 'nbody', 'ngeom', 'nsite', 'nsensor'):
    assert getattr(mine, size) == getattr(theirs, size), size
  names = lambda m, n, f: [f(m, i).name for i in range(n)]
  assert names(mine, mine.nbody, type(mine).body) == names(
      theirs, theirs.nbody, type(theirs).body
  )
  for i in range(1, mine.njnt):  # The freejoint: 'walker/' in dm_control.
    assert mine.joint(i).name == theirs.joint(i).name
  np.testing.assert_allclose(mine.body_mass, theirs.body_mass, rtol=1e-6)
  np.testing.assert_allclose(mine.geom_size, theirs.geom_size, rtol=1e-6)


def test_observations_reward_and_termination_equal_dm_control(port, reference):
  env, task, states = port
  dm_env, dm_task = reference
  physics = dm_env.physics
  observables = _enabled(task)
  dm_observables = _enabled(dm_task)

  @jax.jit
  def evaluate(state):
    p = env.physics(state).forward()
    observations = {
        k: o.observation_callable(p, jax.random.key(0))()
        for k, o in observables.items()
    }
    p = task.after_step(p, jax.random.key(0))
    return observations, task.get_reward(p), task.should_terminate_episode(p)

  errors, terminations = {}, []
  for state in states:
    for world in range(_BATCH):
      one = jax.tree.map(lambda x, w=world: x[w], state)
      observations, reward, terminate = evaluate(one)
      physics.data.qpos[:] = np.asarray(one.data.qpos)
      physics.data.qvel[:] = np.asarray(one.data.qvel)
      physics.data.ctrl[:] = np.asarray(one.data.ctrl)
      physics.forward()
      mjlib.mj_subtreeVel(physics.model.ptr, physics.data.ptr)
      for name, observable in dm_observables.items():
        expected = np.asarray(
            observable.observation_callable(physics, np.random.RandomState(0))()
        )
        actual = np.asarray(observations[name]).reshape(expected.shape)
        if not expected.size:  # e.g. the Ant's force sensors: none.
          continue
        scale = np.maximum(np.abs(expected), 1.0)
        errors[name] = max(
            errors.get(name, 0.0),
            float(np.max(np.abs(actual - expected) / scale)),
        )
      errors['reward'] = max(
          errors.get('reward', 0.0),
          abs(float(reward) - dm_task.get_reward(physics)),
      )
      dm_task.after_step(physics, np.random.RandomState(0))
      terminations.append(
          (bool(terminate), dm_task.should_terminate_episode(physics))
      )
  # Errors relative to max(|x|, 1). Positions, velocities, frames, touch and
  # the reward: float32 rounding. The accelerometer reads accelerations that
  # the constraint solver computes, iteratively, in float32 on MJX and in
  # float64 in MuJoCo: it agrees to the solver's float32 precision.
  accelerations = {'walker/sensors_accelerometer'}
  for name, error in errors.items():
    assert error < (1e-4 if name in accelerations else 1e-6), (name, errors)
  assert all(mine == theirs for mine, theirs in terminations), terminations
