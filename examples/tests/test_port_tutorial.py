"""dm_control's composer tutorial ported (`examples/ports/tutorial`).

`tutorial.py` is `dm_control_tutorial.py` (dm_control's own code) with its
imports changed and its hooks made pure. The port runs batched (3 worlds,
2 control steps, one environment for the module); on the same state (qpos,
qvel, the button's pose and press count set alike) its observations, the
button's activation and the reward equal dm_control's (MuJoCo's C library on
the host) to float32 rounding, a state with the creature standing on the
button included, except the force on the button where a foot touches it
(MJX's capsule-cylinder contacts differ from MuJoCo's). The noise (composer's corruptors) is checked by
its distribution. `docs/porting.md` shows the diff between the two modules:
the docs test below keeps it current.
"""

import difflib
import pathlib
import re

from dm_control import composer as dm_composer
import jax
import numpy as np
import pytest

# examples/ports/tutorial/
import dm_control_tutorial as reference_module
import tutorial as port_module

_ROOT = pathlib.Path(__file__).resolve().parents[2]
_PORT = _ROOT / 'examples' / 'ports' / 'tutorial'

_BATCH = 3
_STEPS = 2


@pytest.fixture(scope='module')
def port():
  """The port's environment, reset and stepped batched."""
  env = port_module.make_environment()
  reset = jax.jit(jax.vmap(env.reset))
  step = jax.jit(jax.vmap(env.step))
  actions = np.random.RandomState(0).uniform(-1, 1, (_STEPS, _BATCH, 8))
  states = [reset(jax.random.split(jax.random.key(0), _BATCH))]
  for action in actions.astype(np.float32):
    states.append(step(states[-1], action))
  return env, jax.device_get(states)


@pytest.fixture(scope='module')
def reference():
  """dm_control's tutorial environment (composer's, on the host)."""
  env = reference_module.make_environment()
  env.reset()
  return env


def _named(values):
  """A dict keyed by observable names without their entity's prefix."""
  return {k.split('/')[-1]: v for k, v in values.items()}


def _by_name(observables):
  """Enabled observables keyed by their own name (the part after '/')."""
  return {k: o for k, o in _named(observables).items() if o.enabled}


def _world(state, world):
  return jax.tree.map(lambda x: x[world], state)


def test_runs_batched(port, reference):
  env, states = port
  names = {'joint_positions', 'joint_velocities', 'touch_force'}
  names.add('button_position')
  assert set(_named(states[0].observation)) == names
  assert set(_named(reference.observation_spec())) == names
  for state in states:
    for value in state.observation.values():
      assert np.asarray(value).shape[0] == _BATCH
      assert np.all(np.isfinite(np.asarray(value)))
  assert list(np.asarray(states[0].step_type)) == [0] * _BATCH  # FIRST
  assert list(np.asarray(states[-1].step_type)) == [1] * _BATCH  # MID
  np.testing.assert_allclose(  # float32 time
      np.asarray(states[-1].data.time),
      _STEPS * env.control_timestep(),
      rtol=1e-6,
  )
  # composer's initial poses: the creature at (0, 0, 0.15), upright; the
  # button on a circle of radius U(0.5, 0.75) around it, each world its own.
  qpos = np.asarray(states[0].data.qpos)
  np.testing.assert_allclose(qpos[:, :7], [[0, 0, 0.15, 1, 0, 0, 0]] * _BATCH)
  button = _named(states[0].observation)['button_position'][:, 0]
  distance = np.linalg.norm(button[:, :2], axis=-1)
  assert np.all((distance >= 0.5) & (distance <= 0.75)), distance
  np.testing.assert_allclose(button[:, 2], 0.0)
  assert len(set(np.round(distance, 6))) == _BATCH


def _set_state(physics, dm_button, one, button_frame_id, count):
  """Puts the port's world state `one` into dm_control's physics."""
  physics.data.qpos[:] = np.asarray(one.data.qpos)
  physics.data.qvel[:] = np.asarray(one.data.qvel)
  physics.data.ctrl[:] = np.asarray(one.data.ctrl)
  physics.model.body_pos[button_frame_id] = np.asarray(
      one.model_fields['body_pos'][button_frame_id]
  )
  physics.forward()
  dm_button._num_activated_steps = count  # pylint: disable=protected-access


def _standing(one, frame, height):
  """`one` with the creature's torso at `height` above its button's centre."""
  qpos = np.asarray(one.data.qpos).copy()
  qpos[:2] = np.asarray(one.model_fields['body_pos'][frame][:2])
  qpos[2] = height
  return one.replace(data=one.data.replace(qpos=qpos))


def _pressing_height(physics, frame):
  """A torso height at which the upright creature presses its button in range.

  The button's top is at z = 0.02 and the feet hang 0.12 below the torso:
  of the heights that push the feet 0 to 10 mm into the button, the one
  whose touch force (MuJoCo's C library) is nearest the middle of [5, 10] N.
  """
  qpos0 = physics.data.qpos.copy()
  heights = 0.14 - np.linspace(0.0, 0.01, 21)
  forces = []
  for height in heights:
    physics.data.qpos[:] = qpos0
    physics.data.qpos[:2] = physics.model.body_pos[frame][:2]
    physics.data.qpos[2] = height
    physics.data.qpos[3:7] = [1, 0, 0, 0]
    physics.data.qpos[7:] = 0
    physics.data.qvel[:] = 0
    physics.forward()
    forces.append(physics.data.sensordata[0])
  physics.data.qpos[:] = qpos0
  return heights[np.argmin(np.abs(np.asarray(forces) - 7.5))]


def test_observations_activation_and_reward_equal_dm_control(port, reference):
  env, states = port
  task = env.task
  button = task._button  # pylint: disable=protected-access
  dm_button = reference.task._button  # pylint: disable=protected-access
  physics = reference.physics
  frame = physics.model.name2id(dm_button.mjcf_model.model + '/', 'body')
  assert env.mj_model.body(frame).name == physics.model.id2name(frame, 'body')
  observables = _by_name(task.observables)
  dm_observables = _by_name(reference.task.observables)

  @jax.jit
  def evaluate(one):
    p = env.physics(one).forward()
    raw = {k: o.raw_observation_callable(p)() for k, o in observables.items()}
    p = button._update_activation(p)  # pylint: disable=protected-access
    rgba = p.bind(button._geom).rgba  # pylint: disable=protected-access
    return raw, button.num_activated_steps(p), rgba, task.get_reward(p)

  errors = {}
  touched = 0
  for state in states:
    for world in range(_BATCH):
      one = _world(state, world)
      _set_state(physics, dm_button, one, frame, 0)
      height = _pressing_height(physics, frame)
      for standing, one in enumerate((one, _standing(one, frame, height))):
        raw, count, rgba, reward = evaluate(one)
        start = int(
            one.entity_states[button.full_identifier]['num_activated_steps']
        )
        _set_state(physics, dm_button, one, frame, start)
        for name, observable in dm_observables.items():
          corruptor, observable.corruptor = observable.corruptor, None
          expected = np.asarray(
              observable.observation_callable(physics, None)()
          )
          observable.corruptor = corruptor
          actual = np.asarray(raw[name]).reshape(expected.shape)
          scale = np.maximum(np.abs(expected), 1.0)
          if standing and name == 'touch_force':
            # MJX's contacts between the capsule feet and the cylinder (or
            # their forces) differ from MuJoCo's C library's: the force
            # differed by up to 43%. Compared where no foot touches it.
            continue
          errors[name] = max(
              errors.get(name, 0.0),
              float(np.max(np.abs(actual - expected) / scale)),
          )
        touched += int(physics.data.sensordata[0] > 1.0)
        dm_button._update_activation(physics)  # pylint: disable=protected-access
        assert int(count) == dm_button.num_activated_steps
        np.testing.assert_array_equal(
            np.asarray(rgba),
            physics.bind(dm_button._geom).rgba,  # pylint: disable=protected-access
        )
        np.testing.assert_allclose(
            float(reward), reference.task.get_reward(physics), rtol=1e-6
        )
  # float32 rounding of values of order one (errors relative to max(|x|, 1)).
  assert max(errors.values()) < 2e-5, errors
  # The standing states press the button (MuJoCo's force mid-range).
  assert touched >= _BATCH, touched


def test_reset_activation_equals_dm_control(port, reference):
  """The `Button`'s `initialize_episode` reads its touch sensor after the
  task moved the creature and the button, with no forward pass between;
  composer's reset context forwards before that read, and so does ours:
  the press count and the colour at reset are dm_control's on that state."""
  env, states = port
  button = env.task._button  # pylint: disable=protected-access
  dm_button = reference.task._button  # pylint: disable=protected-access
  physics = reference.physics
  frame = physics.model.name2id(dm_button.mjcf_model.model + '/', 'body')
  geom = physics.bind(dm_button._geom).element_id  # pylint: disable=protected-access
  # The colour, written by the button's hooks, is found to be per world.
  assert set(env.per_world_model_fields['geom_rgba']) == {
      f'Button({button.name!r}).initialize_episode',
      f'Button({button.name!r}).after_substep',
  }
  for world in range(_BATCH):
    one = _world(states[0], world)
    _set_state(physics, dm_button, one, frame, 0)
    dm_button.initialize_episode(physics, None)
    count = one.entity_states[button.full_identifier]['num_activated_steps']
    assert int(count) == dm_button.num_activated_steps
    np.testing.assert_array_equal(
        np.asarray(one.model_fields['geom_rgba'][geom]),
        physics.bind(dm_button._geom).rgba,  # pylint: disable=protected-access
    )


def test_observation_noise_is_composers(port):
  """Additive N(0, 0.01) on positions, multiplicative LogN(0, 0.01) on speeds."""
  _, states = port
  # The creature's joints are all hinges, after its freejoint (7 qpos, 6 dofs).
  position_noise, speed_log_ratio = [], []
  for state in states:
    obs = _named(state.observation)
    qpos = np.asarray(state.data.qpos)[:, 7:]
    qvel = np.asarray(state.data.qvel)[:, 6:]
    position_noise.append(obs['joint_positions'][:, 0] - qpos)
    moving = np.abs(qvel) > 1e-2
    speed_log_ratio.append(
        np.log(obs['joint_velocities'][:, 0][moving] / qvel[moving])
    )
  position_noise = np.concatenate(position_noise).ravel()
  speed_log_ratio = np.concatenate(speed_log_ratio)
  # 48 and >= 20 samples: their standard deviation is within 40% of the
  # distribution's with a margin of over 4 standard errors.
  assert speed_log_ratio.size >= 20
  for samples in (position_noise, speed_log_ratio):
    assert np.all(np.abs(samples) < 0.05), samples  # 5 sigma
    assert 0.006 < np.std(samples) < 0.014, np.std(samples)


def test_the_porting_guide_shows_the_current_diff():
  """docs/porting.md's diff is the diff between the two modules."""
  docs = (_ROOT / 'docs' / 'porting.md').read_text()
  section = docs.split("## Porting dm_control's tutorial", 1)[1]
  shown = re.search(r'```diff\n(.*?)```', section, re.S).group(1)
  assert shown == tutorial_diff(), 'regenerate it with tutorial_diff()'


def tutorial_diff() -> str:
  """The unified diff of the two modules' code (their headers left out)."""

  def code(name):
    text = (_PORT / name).read_text()
    return text[text.index('# PyMJCF') :].splitlines(keepends=True)

  return ''.join(
      difflib.unified_diff(
          code('dm_control_tutorial.py'),
          code('tutorial.py'),
          'dm_control_tutorial.py',
          'tutorial.py',
          n=1,
      )
  )


def test_the_reference_is_dm_controls(reference):
  """The reference module runs as dm_control's composer runs the tutorial."""
  assert isinstance(reference, dm_composer.Environment)
  timestep = reference.step(np.zeros(8))
  assert np.isfinite(timestep.reward)
