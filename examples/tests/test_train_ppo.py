"""examples/train_ppo.py's rollout metrics, on a small composed task."""

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.adapters import brax as brax_adapter
from tests import conftest

import train_ppo  # examples/train_ppo.py

_WORLDS = 3
_STEPS = 7  # episodes of 5 control steps: the rollout crosses an auto-reset
_SEED = 4


@pytest.fixture(scope='module')
def brax_env():
  env = conftest.make_swing_env(
      time_limit=0.05,
      options=composer.ExecutionOptions(auto_reset='same_step'),
  )
  return brax_adapter.BraxEnv(env, obs_key='tip')


@pytest.fixture(scope='module')
def fns(brax_env):
  return {'reset': jax.jit(brax_env.reset), 'step': jax.jit(brax_env.step)}


@pytest.fixture(scope='module')
def written(brax_env, tmp_path_factory):
  """`write_rollout_metrics`' payload and its file, computed once.

  It holds `rollout_metrics` of the policy and of zero actions, which the
  tests below check against a step-by-step reference (each rollout is a
  program of its own to compile).
  """
  out = tmp_path_factory.mktemp('rollout_metrics')
  args = argparse.Namespace(
      metrics_worlds=_WORLDS, render_steps=_STEPS, seed=_SEED - 1
  )
  payload = train_ppo.write_rollout_metrics(
      brax_env, _constant_policy(0.5), args, str(out)
  )
  with open(out / 'rollout_metrics.json') as f:
    return payload, json.load(f)


def _constant_policy(value):
  def policy(obs, unused_key):
    return jnp.full(obs.shape[:-1] + (1,), value), {}

  return policy


def _step_by_step(fns, action):
  """The per-step means of a Python loop over jitted steps (the reference)."""
  reset_key, _ = jax.random.split(jax.random.PRNGKey(_SEED))
  state = fns['reset'](jax.random.split(reset_key, _WORLDS))
  per_step = []
  for _ in range(_STEPS):
    state = fns['step'](state, jnp.full((_WORLDS, 1), action))
    metrics = brax_adapter.composer_state(state).metrics
    row = {
        name: np.mean(value)
        for name, value in metrics.items()
        if np.issubdtype(value.dtype, np.floating)
    }
    row['reward'] = np.mean(state.reward)
    per_step.append(row)
  return {name: np.mean([r[name] for r in per_step]) for name in per_step[0]}


def test_rollout_metrics_average_every_world_and_step(written, fns):
  got = written[0]['policy']  # rollout_metrics of the constant policy
  want = _step_by_step(fns, 0.5)
  assert set(got) == set(want)
  assert {'reward', 'episode_return', 'diverged'} <= set(got)
  for name in want:
    np.testing.assert_allclose(got[name], want[name], rtol=1e-5, atol=1e-7)


def test_zero_actions_baseline(written, fns):
  zero = written[0]['zero_actions']  # rollout_metrics with policy None
  want = _step_by_step(fns, 0.0)
  for name in want:
    np.testing.assert_allclose(zero[name], want[name], rtol=1e-5, atol=1e-7)


def test_write_rollout_metrics_compares_policy_and_zero_actions(written):
  payload, from_file = written
  assert from_file == payload
  assert (from_file['worlds'], from_file['steps'], from_file['seed']) == (
      _WORLDS,
      _STEPS,
      _SEED,
  )
  # The policy's actions reach the worlds: the reward differs.
  assert from_file['policy']['reward'] != from_file['zero_actions']['reward']


def test_auto_reset_batch_reaches_the_environment():
  args = train_ppo.parse_args(['--task', 'reach', '--auto-reset-batch', '4'])
  env, brax_env = train_ppo.make_brax_env(args)
  # Batched resets need the separate restart, also on a CPU (whose default
  # shares the sub-step loop).
  assert env.auto_reset_batch == 4 and not env.share_reset_forward
  assert brax_env.environment is env
  default_env, _ = train_ppo.make_brax_env(train_ppo.parse_args([]))
  assert default_env.auto_reset_batch is None


def test_like_playground_builds_train_compares_ours_off():
  args = train_ppo.parse_args(['--task', 'walk', '--like-playground'])
  env, brax_env = train_ppo.make_brax_env(args)
  # HumanoidWalk's observation alone, none of the shipped task's additions.
  assert set(brax_env.observation_size) == {'policy'}
  # HumanoidWalk's 67 values: no history stacked onto them.
  assert brax_env.observation_size['policy'] == (67,)
  default_env, default_brax = train_ppo.make_brax_env(
      train_ppo.parse_args(['--task', 'walk'])
  )
  assert 'critic' in default_brax.observation_size
  assert env.time_limit == default_env.time_limit


def test_like_playground_is_for_the_walk_task_only():
  with pytest.raises(SystemExit):
    train_ppo.parse_args(['--task', 'reach', '--like-playground'])
