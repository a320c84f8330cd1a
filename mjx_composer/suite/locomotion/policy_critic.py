"""The policy's and the critic's observations of a locomotion task.

The asymmetric actor-critic split that MuJoCo Playground's and Isaac Lab's
locomotion tasks train with, on composer's observables:

* `policy_observable`: the policy sees an observable once per control step,
  corrupted (`uniform_noise`: Playground's sensor noise), late and with a
  history;
* `clean_twin`: the critic sees a clean, current copy of it;
* `split_policy_and_critic`: both, for a list of an entity's observables.
"""

import copy

import jax
import jax.numpy as jnp

from mjx_composer.utils import validation


def uniform_noise(scale):
  """A corruptor adding U(-scale, scale) noise per entry (Playground's)."""

  def corrupt(value, key):
    value = jnp.asarray(value)
    noise = jax.random.uniform(
        key, value.shape, value.dtype, minval=-1.0, maxval=1.0
    )
    return value + scale * noise

  return corrupt


def policy_observable(obs, n_sub_steps, corruptor=None, delay=0, history=1):
  """Configures `obs` as a policy input: noisy, late, with a history.

  The observable is sampled once per control step (at its boundaries), each
  sample corrupted by `corruptor` and visible `delay` physics sub-steps
  after it is taken, and the observation holds the last `history` visible
  samples, oldest first. A `delay` between 1 and `n_sub_steps` therefore
  shows the policy the previous control step's reading: the sensor's value
  reaches the policy after the policy has read its inputs.

  Returns:
    `obs`, enabled and configured.

  Raises:
    TypeError, ValueError: for an `obs` without `configure`, a `corruptor`
      that is neither None nor callable, or a count that is not an integer
      (`delay` >= 0, `n_sub_steps` and `history` >= 1): `2.5` is refused
      rather than truncated.
  """
  owner = 'policy_observable'
  if not callable(getattr(obs, 'configure', None)):
    raise TypeError(
        f'{owner}: obs must be an observable, got {obs!r}. Pass e.g. '
        'robot.observables.joints_pos or observable.Generic(fn).'
    )
  n_sub_steps = validation.check_integer(
      'n_sub_steps', n_sub_steps, owner=owner, minimum=1
  )
  if corruptor is not None and not callable(corruptor):
    raise TypeError(
        f'{owner}: corruptor must be None or a callable '
        f'corruptor(value, key) -> value, got {corruptor!r}. Pass e.g. '
        'uniform_noise(0.05).'
    )
  delay = validation.check_integer('delay', delay, owner=owner, minimum=0)
  history = validation.check_integer('history', history, owner=owner, minimum=1)
  obs.configure(
      enabled=True,
      update_interval=n_sub_steps,
      corruptor=corruptor,
      delay=delay,
      buffer_size=history,
  )
  return obs


def clean_twin(obs):
  """A copy of `obs` read directly: no noise, latency, history or rate.

  For the critic's group: the updater applies an observable's delay and
  buffer to every group that selects it (a clean group only skips the
  corruptor), so privileged, current values need an observable of their
  own. Register the twin as a task observable.
  """
  twin = copy.copy(obs)
  twin.configure(
      enabled=True,
      update_interval=1,
      corruptor=None,
      delay=0,
      buffer_size=1,
      aggregator=None,
  )
  return twin


def split_policy_and_critic(
    observables,
    policy,
    privileged,
    n_sub_steps,
    noise_scales,
    noise_level,
    delay,
    history,
    with_history,
):
  """Configures an entity's observables for a policy group and a critic group.

  Args:
    observables: the entity's `Observables`.
    policy: names of the policy's inputs, each made a `policy_observable`
      with uniform noise of `noise_level * noise_scales.get(name, 0)`.
    privileged: names enabled for the critic only.
    n_sub_steps: physics steps per control step.
    noise_scales: `{name: noise scale}`.
    noise_level: multiplies every noise scale (0: no noise).
    delay: the policy inputs' delay, in physics sub-steps.
    history: samples kept for the names in `with_history` (others keep 1).
    with_history: names of policy inputs with a history.

  Returns:
    `{'privileged_<name>': clean_twin(...)}` for every policy input: the
    critic's clean, current copies, to register as task observables.
  """
  twins = {}
  for name in policy:
    obs = observables.get_observable(name)
    scale = noise_level * noise_scales.get(name, 0.0)
    policy_observable(
        obs,
        n_sub_steps,
        corruptor=uniform_noise(scale) if scale else None,
        delay=delay,
        history=history if name in with_history else 1,
    )
    twins[f'privileged_{name}'] = clean_twin(obs)
  for name in privileged:
    observables.get_observable(name).enabled = True
  return twins
