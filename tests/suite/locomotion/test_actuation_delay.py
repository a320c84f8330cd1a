"""ActuationDelay: sub-step t runs with the controls set for sub-step t - d.

A pendulum's motor is delayed by a per-world draw from (0, 4) sub-steps,
three sub-steps per control step, so delays reach into the previous control
step and beyond. The reference is MuJoCo's C library stepping the compiled
model undelayed with the control sequence shifted by each world's drawn
delay (the episode's initial control before the start).
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.suite.locomotion import actuation_delay
from tests import conftest

_WORLDS = 4
_STEPS = 5
_SUB_STEPS = 3
_INITIAL = 10.0  # The initial control (torque), N m.


class _DelayedSwing(conftest.PendulumTask):

  def __init__(self, delay_range):
    self.arena = composer.Arena()
    self.pendulum = conftest.Pendulum(ctrllimited=False, damping=0.0)
    self.arena.attach(self.pendulum)
    self.set_timesteps(
        control_timestep=0.01 * _SUB_STEPS, physics_timestep=0.01
    )
    self.delay = actuation_delay.ActuationDelay(
        self.pendulum.actuators, delay_range
    )

  def initial_task_state(self):
    return self.delay.initial_state()

  def initialize_episode(self, physics, key):
    physics = physics.set_control(jnp.full((1,), _INITIAL))
    return self.delay.reset(physics, key)

  def before_substep(self, physics, action, key):
    return self.delay.before_substep(physics)

  def after_substep(self, physics, key):
    return self.delay.after_substep(physics)

  def get_reward(self, physics):
    return 0.0


@pytest.fixture(scope='module')
def run():
  env = composer.Environment(_DelayedSwing((0, 4)), time_limit=1.0)
  state = jax.jit(jax.vmap(env.reset))(
      jax.random.split(jax.random.key(3), _WORLDS)
  )
  step = jax.jit(jax.vmap(env.step))
  actions = np.random.default_rng(0).uniform(-20, 20, (_STEPS, _WORLDS, 1))
  states = [state]
  for action in actions:
    states.append(step(states[-1], jnp.asarray(action, jnp.float32)))
  return env, jax.device_get(states), actions


def test_delays_are_drawn_per_world_in_the_range(run):
  _, states, _ = run
  delays = states[0].task_state['actuation_delay_steps']
  assert np.all((delays >= 0) & (delays <= 4))
  assert len(np.unique(delays)) > 1
  for state in states[1:]:  # Drawn once per episode.
    np.testing.assert_array_equal(
        state.task_state['actuation_delay_steps'], delays
    )


def test_delayed_actuation_is_the_undelayed_one_shifted(run):
  env, states, actions = run
  model = env.mj_model
  for world in range(_WORLDS):
    delay = int(states[0].task_state['actuation_delay_steps'][world])
    undelayed = np.repeat(actions[:, world, 0], _SUB_STEPS)
    shifted = np.concatenate([np.full(delay, _INITIAL), undelayed])
    runs = {}
    for name, targets in (('shifted', shifted), ('undelayed', undelayed)):
      data = mujoco.MjData(model)
      data.qpos[:] = states[0].data.qpos[world]
      data.qvel[:] = states[0].data.qvel[world]
      runs[name] = []
      for i in range(_STEPS):
        for j in range(_SUB_STEPS):
          data.ctrl[0] = targets[i * _SUB_STEPS + j]
          mujoco.mj_step(model, data)
        runs[name].append(data.qpos.copy())
    for i in range(_STEPS):
      after = states[i + 1]
      np.testing.assert_allclose(
          after.data.qpos[world], runs['shifted'][i], rtol=1e-4, atol=1e-5
      )
      # `ctrl` reads what the task set, not the delayed control.
      np.testing.assert_allclose(
          after.data.ctrl[world, 0], actions[i, world, 0], rtol=1e-6
      )
    # The delay matters: undelayed, the pendulum ends elsewhere.
    gap = np.abs(runs['undelayed'][-1] - states[-1].data.qpos[world])
    assert (gap > 1e-3).all() == (delay > 0)


@pytest.mark.parametrize(
    'delay_range, match',
    [
        ((2, 1), 'delay_range'),
        ((0, 1.5), r'delay_range\[1\]'),
        ((-1, 2), r'delay_range\[0\]'),
        ((1,), 'delay_range'),
    ],
)
def test_bad_ranges_are_refused_by_name(delay_range, match):
  with pytest.raises((TypeError, ValueError), match=match):
    actuation_delay.ActuationDelay(conftest.Pendulum().actuators, delay_range)
