"""Velocity commands: what a locomotion policy is asked to do, per world.

`VelocityCommand` is the command manager of Isaac Lab's and mjlab's velocity
tasks (`UniformVelocityCommand`) as a reusable part a task composes: each
world carries its own command (forward and lateral velocity, yaw rate), drawn
at the episode's start and redrawn every `resample_interval` control steps,
in the task's per-world state. Optional features, each off by default:

* a share of standing worlds (`standing_share`): at each draw a world is
  told to stand still (a zero command) with that probability;
* heading control (`heading_range`): a heading is drawn instead of a yaw
  rate, and every step the yaw rate is `heading_stiffness` times the
  wrapped heading error, clipped to `ang_vel_z`;
* Playground's resampling rule (`keep_probability`, `zero_probability`):
  at a resample each entry keeps its old value with `keep_probability`,
  else takes a new draw that is zeroed with its `zero_probability`.

A task declares the command's entries in its task state
(`initial_task_state() | command.initial_state()`), draws the first command
in `initialize_episode` (`command.reset(physics, key)`) and advances it in
`before_step` (`command.step(physics, key, heading=...)`). Rewards read
`command.velocity(physics)`; `command.observable()` is the policy's input.
"""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.observation import observable
from mjx_composer.utils import validation

_OWNER = 'VelocityCommand'


def wrap_angle(angle):
  """`angle` wrapped to [-pi, pi)."""
  return (angle + np.pi) % (2 * np.pi) - np.pi


class VelocityCommand:
  """A per-world planar velocity command (module docstring).

  Args:
    lin_vel_x: (low, high) of the forward velocity, m/s.
    lin_vel_y: (low, high) of the lateral velocity, m/s.
    ang_vel_z: (low, high) of the yaw rate, rad/s (with heading control,
      the clip of the heading controller's output).
    resample_interval: control steps between draws (0: only at the
      episode's start).
    standing_share: the probability that a draw is a standing command.
    heading_range: (low, high) of the commanded heading in radians, or None
      for a commanded yaw rate.
    heading_stiffness: yaw rate per radian of heading error.
    keep_probability: at a resample, the probability that an entry keeps
      its old value (0: every entry is redrawn).
    zero_probability: at a resample, the probability that a new entry is
      zero, per entry (vx, vy, yaw rate); the episode's first draw is never
      zeroed.
    name: the task-state entries' prefix (`name`, `name + '_heading'`, ...).
  """

  def __init__(
      self,
      lin_vel_x=(-1.0, 1.0),
      lin_vel_y=(-1.0, 1.0),
      ang_vel_z=(-1.0, 1.0),
      resample_interval=250,
      standing_share=0.0,
      heading_range=None,
      heading_stiffness=0.5,
      keep_probability=0.0,
      zero_probability=(0.0, 0.0, 0.0),
      name='command',
  ):
    ranges = [
        validation.check_range_pair(arg, value, owner=_OWNER)
        for arg, value in (
            ('lin_vel_x', lin_vel_x),
            ('lin_vel_y', lin_vel_y),
            ('ang_vel_z', ang_vel_z),
        )
    ]
    self.low = np.array([r[0] for r in ranges], np.float32)
    self.high = np.array([r[1] for r in ranges], np.float32)
    self.resample_interval = validation.check_integer(
        'resample_interval', resample_interval, owner=_OWNER, minimum=0
    )
    self.standing_share = validation.check_probability(
        'standing_share', standing_share, owner=_OWNER
    )
    self.heading_range = (
        None
        if heading_range is None
        else validation.check_range_pair(
            'heading_range', heading_range, owner=_OWNER
        )
    )
    self.heading_stiffness = validation.check_nonnegative(
        'heading_stiffness', heading_stiffness, owner=_OWNER
    )
    self.keep_probability = validation.check_probability(
        'keep_probability', keep_probability, owner=_OWNER
    )
    zero = np.asarray(
        validation.check_probability(
            'zero_probability', zero_probability, owner=_OWNER
        ),
        np.float32,
    )
    if zero.shape != (3,):
      raise ValueError(
          f'{_OWNER}: zero_probability must have 3 entries (vx, vy, yaw '
          f'rate), got {zero_probability!r}. Pass e.g. (0.1, 0.75, 0.5).'
      )
    self.zero_probability = zero
    if not isinstance(name, str) or not name:
      raise TypeError(
          f'{_OWNER}: name must be a non-empty string, got {name!r}.'
      )
    self.name = name

  # -- state -----------------------------------------------------------------

  def initial_state(self):
    """The task-state entries this command keeps (merge them into yours).

    `<name>`: the (3,) command (vx, vy, yaw rate); `<name>_heading`: the
    commanded heading (unused without heading control); `<name>_standing`:
    whether the world stands still; `<name>_steps`: control steps begun
    since the last draw.
    """
    return {
        self.name: jnp.zeros(3, jnp.float32),
        f'{self.name}_heading': jnp.zeros((), jnp.float32),
        f'{self.name}_standing': jnp.zeros((), bool),
        f'{self.name}_steps': jnp.zeros((), jnp.int32),
    }

  def velocity(self, physics):
    """This world's command (3,): (vx, vy) in the robot's frame, yaw rate."""
    return physics.task_state[self.name]

  def standing(self, physics):
    """Whether this world is told to stand still (a bool scalar)."""
    return physics.task_state[f'{self.name}_standing']

  def observable(self):
    """An (enabled) observable of the command, for the policy's inputs."""
    obs = observable.Generic(self.velocity)
    obs.enabled = True
    return obs

  # -- draws -----------------------------------------------------------------

  def _uniform(self, key):
    return jax.random.uniform(key, (3,), minval=self.low, maxval=self.high)

  def _standing(self, key):
    if self.standing_share <= 0.0:
      return jnp.zeros((), bool)
    return jax.random.bernoulli(key, self.standing_share)

  def _heading(self, key):
    if self.heading_range is None:
      return jnp.zeros((), jnp.float32)
    low, high = self.heading_range
    return jax.random.uniform(key, (), minval=low, maxval=high)

  def sample(self, key):
    """The episode's first command: `(velocity (3,), heading, standing)`."""
    velocity = self._uniform(key)
    standing = self._standing(jax.random.fold_in(key, 1))
    heading = self._heading(jax.random.fold_in(key, 2))
    return velocity, heading, standing

  def resample(self, key, old):
    """A redraw from `old` (3,): `(velocity (3,), heading, standing)`.

    Each entry keeps its old value with `keep_probability`, else takes a
    new uniform draw, zeroed with its `zero_probability`.
    """
    new_key, zero_key, keep_key = jax.random.split(key, 3)
    new = self._uniform(new_key)
    nonzero = jax.random.bernoulli(zero_key, 1.0 - self.zero_probability)
    change = jax.random.bernoulli(keep_key, 1.0 - self.keep_probability, (3,))
    velocity = jnp.where(change, new * nonzero, old)
    standing = self._standing(jax.random.fold_in(key, 1))
    heading = self._heading(jax.random.fold_in(key, 2))
    return velocity, heading, standing

  # -- hooks the task calls ---------------------------------------------------

  def _write(self, physics, velocity, heading, standing, steps, yaw):
    velocity = self._track_heading(velocity, heading, yaw)
    velocity = jnp.where(standing, 0.0, velocity).astype(jnp.float32)
    return physics.update_task_state(
        **{
            self.name: velocity,
            f'{self.name}_heading': jnp.asarray(heading, jnp.float32),
            f'{self.name}_standing': jnp.asarray(standing, bool),
            f'{self.name}_steps': jnp.asarray(steps, jnp.int32),
        }
    )

  def _track_heading(self, velocity, heading, yaw):
    if self.heading_range is None or yaw is None:
      return velocity
    rate = self.heading_stiffness * wrap_angle(heading - yaw)
    rate = jnp.clip(rate, self.low[2], self.high[2])
    return velocity.at[2].set(rate)

  def reset(self, physics, key, heading=None):
    """Draws the episode's first command (call from `initialize_episode`).

    Args:
      physics: one world's `Physics` whose task state holds
        `initial_state()`'s entries.
      key: a PRNG key for the draw.
      heading: the robot's current heading (yaw, radians), needed with
        heading control; ignored without.
    """
    self._require_heading(heading)
    velocity, target, standing = self.sample(key)
    return self._write(physics, velocity, target, standing, 0, heading)

  def step(self, physics, key, heading=None):
    """Advances the command by one control step (call from `before_step`).

    Once `resample_interval` control steps have completed since the last
    draw, the command is redrawn (`resample`) before this step runs: the
    draws come at the starts of steps k+1, 2k+1, ... of the episode. With
    heading control the yaw rate follows the heading error every step.
    """
    self._require_heading(heading)
    state = physics.task_state
    velocity = state[self.name]
    target = state[f'{self.name}_heading']
    standing = state[f'{self.name}_standing']
    steps = state[f'{self.name}_steps']
    if self.resample_interval > 0:
      due = steps >= self.resample_interval
      new = self.resample(key, velocity)
      velocity = jnp.where(due, new[0], velocity)
      target = jnp.where(due, new[1], target)
      standing = jnp.where(due, new[2], standing)
      steps = jnp.where(due, 0, steps)
    return self._write(physics, velocity, target, standing, steps + 1, heading)

  def _require_heading(self, heading):
    if self.heading_range is not None and heading is None:
      raise ValueError(
          f"{_OWNER}(heading_range={self.heading_range}) needs the robot's "
          'heading: pass heading=<yaw in radians> to reset and step.'
      )
