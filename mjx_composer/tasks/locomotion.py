"""Pieces the locomotion tasks (`walk`, `joystick`) share.

* `tolerance`: dm_control's `rewards.tolerance` (the shaped reward of the
  suite and of Playground's dm_control tasks), in `jax.numpy`.
* Corruptors: `uniform_noise` (Playground's sensor noise).
* `policy_observable` / `clean_twin`: the policy sees an observable with
  noise, latency and history; the critic sees a clean, current twin.
* `Pushes`: random horizontal velocity kicks every k control steps.
* `yaw_quaternion`: a rotation about the world's z axis.
"""

import copy

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.utils import validation

# -- rewards -------------------------------------------------------------------


def _sigmoid(x, value_at_1, sigmoid):
  """dm_control's sigmoids: 1 at x = 0, `value_at_1` at |x| = 1."""
  if sigmoid == 'gaussian':
    scale = np.sqrt(-2 * np.log(value_at_1))
    return jnp.exp(-0.5 * (x * scale) ** 2)
  if sigmoid == 'hyperbolic':
    scale = np.arccosh(1 / value_at_1)
    return 1 / jnp.cosh(x * scale)
  if sigmoid == 'long_tail':
    scale = np.sqrt(1 / value_at_1 - 1)
    return 1 / ((x * scale) ** 2 + 1)
  if sigmoid == 'reciprocal':
    scale = 1 / value_at_1 - 1
    return 1 / (jnp.abs(x) * scale + 1)
  if sigmoid == 'cosine':
    scale = np.arccos(2 * value_at_1 - 1) / np.pi
    scaled = x * scale
    inside = jnp.abs(scaled) < 1
    return jnp.where(inside, (1 + jnp.cos(np.pi * scaled)) / 2, 0.0)
  if sigmoid == 'linear':
    scaled = x * (1 - value_at_1)
    return jnp.where(jnp.abs(scaled) < 1, 1 - scaled, 0.0)
  if sigmoid == 'quadratic':
    scaled = x * np.sqrt(1 - value_at_1)
    return jnp.where(jnp.abs(scaled) < 1, 1 - scaled**2, 0.0)
  if sigmoid == 'tanh_squared':
    scale = np.arctanh(np.sqrt(1 - value_at_1))
    return 1 - jnp.tanh(x * scale) ** 2
  raise ValueError(f'Unknown sigmoid type {sigmoid!r}.')


def tolerance(
    x, bounds=(0.0, 0.0), margin=0.0, sigmoid='gaussian', value_at_margin=0.1
):
  """1 where `bounds[0] <= x <= bounds[1]`, decaying outside (dm_control's).

  Args:
    x: the value(s) to judge.
    bounds: (lower, upper); either may be infinite.
    margin: how far outside the bounds the reward falls to
      `value_at_margin`; 0 makes the reward a step function of the bounds.
    sigmoid: the decay's shape: 'gaussian', 'hyperbolic', 'long_tail',
      'reciprocal', 'cosine', 'linear', 'quadratic' or 'tanh_squared'.
    value_at_margin: the reward at distance `margin` from the bounds.
  """
  lower, upper = bounds
  if lower > upper:
    raise ValueError('Lower bound must be <= upper bound.')
  if margin < 0:
    raise ValueError('`margin` must be non-negative.')
  x = jnp.asarray(x, jnp.float32)
  in_bounds = jnp.logical_and(lower <= x, x <= upper)
  if margin == 0:
    return jnp.where(in_bounds, 1.0, 0.0)
  # Outside the bounds exactly one of the two distances is positive; inside,
  # the result is masked (and an infinite bound must not make a NaN there).
  distance = jnp.where(
      x < lower, lower - x, jnp.where(x > upper, x - upper, 0.0)
  )
  return jnp.where(
      in_bounds, 1.0, _sigmoid(distance / margin, value_at_margin, sigmoid)
  )


# -- observations --------------------------------------------------------------


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


# -- perturbations -------------------------------------------------------------


class Pushes:
  """Random horizontal velocity kicks to a free body every k control steps.

  At the start of control steps k+1, 2k+1, ... (after k, 2k, ... completed
  steps) the free joint's linear velocity gets `magnitude * (cos a, sin a,
  0)` added, with a ~ U(-pi, pi) and the magnitude ~ U(*magnitude): what
  Playground's humanoid and quadruped joystick tasks do to train recovery.
  A velocity change is a push of any duration at once, the same for every
  world's (randomized) masses.

  Args:
    interval: k, in control steps (0 or None: never).
    magnitude: (low, high) of the velocity change, m/s.
  """

  def __init__(self, interval, magnitude=(0.1, 1.0)):
    if interval is not None:
      validation.check_integer(
          'interval',
          interval,
          owner='Pushes',
          minimum=0,
          fix='Pass an int >= 0 (0 or None: no pushes).',
      )
    validation.check_range_pair(
        'magnitude', magnitude, owner='Pushes', nonnegative=True
    )
    self.interval = int(interval or 0)
    self.magnitude = tuple(float(m) for m in magnitude)

  def kick(self, step, key):
    """The velocity change (3,) for the control step after `step` steps."""
    if self.interval <= 0:
      return jnp.zeros(3, jnp.float32)
    angle_key, size_key = jax.random.split(key)
    angle = jax.random.uniform(angle_key, (), minval=-np.pi, maxval=np.pi)
    size = jax.random.uniform(
        size_key, (), minval=self.magnitude[0], maxval=self.magnitude[1]
    )
    due = jnp.logical_and(step > 0, step % self.interval == 0)
    kick = size * jnp.stack([jnp.cos(angle), jnp.sin(angle), 0.0])
    return jnp.where(due, kick, 0.0).astype(jnp.float32)

  def apply(self, physics, freejoint, step, key):
    """Returns `(physics, kick)` with the kick added to `freejoint`'s qvel.

    The kick is written into the data as Playground writes it, through
    `physics.named.data` (which leaves composer's physics clean), not
    through a binding (which marks it dirty, so that composer's forward
    pass would end the step): the tasks that push keep raw MJX's timing
    of the sensors read after a step (docs/porting.md, "After a step").
    """
    kick = self.kick(step, key)
    if self.interval <= 0:
      return physics, kick
    qvel = physics.bind(freejoint).qvel
    (joint,) = physics.bind(freejoint).element_ids
    start = int(physics.mj_model.jnt_dofadr[joint])
    dofs = slice(start, start + qvel.shape[-1])
    return physics.named.data.set('qvel', dofs, qvel.at[:3].add(kick)), kick


# -- small helpers -------------------------------------------------------------


def yaw_quaternion(yaw):
  """The quaternion (4,) of a rotation by `yaw` about the world's z axis."""
  return jnp.stack(
      [jnp.cos(yaw / 2), 0.0 * yaw, 0.0 * yaw, jnp.sin(yaw / 2)]
  ).astype(jnp.float32)
