"""`Pushes`: random horizontal velocity kicks that train a robot to recover."""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.utils import validation


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
