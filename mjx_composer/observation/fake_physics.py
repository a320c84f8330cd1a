"""A minimal physics pytree for testing observation timing.

`FakePhysics.time()` is the number of sub-steps since reset, so an observable
that returns `physics.time()` reveals exactly which sub-step each buffered
sample was taken at. `step()` returns a new FakePhysics (it is a pytree, so
it can be carried through `lax.scan`, jitted and vmapped).
"""

import collections

from flax import struct
import jax
import jax.numpy as jnp

from mjx_composer.observation.observable import base


@struct.dataclass
class FakePhysics:
  """A pytree whose clock counts sub-steps.

  Attributes:
    counter: () int32, sub-steps taken since reset.
  """

  counter: jax.Array

  @classmethod
  def create(cls) -> 'FakePhysics':
    return cls(counter=jnp.zeros((), jnp.int32))

  def step(self) -> 'FakePhysics':
    return self.replace(counter=self.counter + 1)

  def time(self) -> jax.Array:
    return self.counter

  def timestep(self) -> float:
    return 1.0

  def sqrt(self) -> jax.Array:
    return jnp.sqrt(self.counter.astype(jnp.float32))

  def sqrt_plus_one(self) -> jax.Array:
    return self.sqrt() + 1.0

  @staticmethod
  def observables() -> 'collections.OrderedDict[str, base.Observable]':
    """Fresh observables `twice`, `repeated` and `matrix`, as in composer."""
    return collections.OrderedDict(
        [
            ('twice', base.Generic(lambda physics: 2 * physics.time())),
            (
                'repeated',
                base.Generic(
                    lambda physics: jnp.stack([physics.time()] * 2),
                    update_interval=5,
                ),
            ),
            (
                'matrix',
                base.Generic(
                    lambda physics: jnp.full((2, 3), physics.time()),
                    update_interval=3,
                ),
            ),
        ]
    )
