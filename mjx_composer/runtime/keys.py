"""The key schedule: how one world's PRNG key is split for each use.

Every random draw of an episode derives from the key `reset` receives, by
the splits and fold-ins below, always in the same order, so that the same
key gives the same trajectory whatever the batch size:

* a reset splits its key into `ResetKeys`: the `initialize_episode` hooks'
  key (an attempt after a failed one folds in the attempt's number), the
  first observation's, and the key the FIRST state carries;
* a control step splits the state's key into `StepKeys`: the scheduled and
  `before_step` hooks', the sub-steps' (each sub-step folds in its index,
  then `SubstepKeys` folds in one number per use), the `after_step` hooks',
  the last observation update's, and the key the next state carries;
* a next-step auto-reset splits the LAST state's key in two
  (`next_step_keys`): the reset's, and the step's whose result is
  discarded;
* with `fixed_initial_state`, every episode of a world starts from the key
  of its first, kept in the world's persistent entries (`INITIAL_KEY`);
* each hook participant folds in the stable id of its identity
  (`hook_keys`), so that overriding one more hook never changes another
  owner's draws.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mjx_composer.utils import stable_id as stable_id_lib

# The persistent entry holding a world's first key (`fixed_initial_state`).
INITIAL_KEY = 'environment/initial_key'


def key_shape() -> jax.ShapeDtypeStruct:
  """A PRNG key's shape and dtype: what analyses of shapes trace with (a
  key made while a program is traced would be staged into it)."""
  return jax.eval_shape(lambda: jax.random.key(0))


def next_step_keys(key) -> tuple[jax.Array, jax.Array]:
  """`(reset_key, step_key)` of a next-step auto-reset's state key."""
  reset_key, step_key = jax.random.split(key)
  return reset_key, step_key


def hook_keys(key, participants) -> list[jax.Array]:
  """The key of each hook participant: `key` with the stable id of its
  identity folded in (`hooks.Participant.identity`), all from one hash."""
  return stable_id_lib.fold_in_each(
      key, [stable_id_lib.stable_id(p.identity) for p in participants]
  )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ResetKeys:
  """A reset's keys, one per use."""

  init: jax.Array
  obs: jax.Array
  next: jax.Array

  @classmethod
  def split(cls, key) -> 'ResetKeys':
    return cls(*jax.random.split(key, 3))

  @staticmethod
  def attempt(init_key, attempts, resample: bool = True) -> jax.Array:
    """The `initialize_episode` key of attempt number `attempts`.

    The first attempt takes `init_key`; with `resample`, a later one folds
    in its number (composer draws on from its random state), else it takes
    `init_key` again (composer's `fixed_initial_state` restores its random
    state instead).
    """
    if not resample:
      return init_key
    return _select_key(
        attempts == 0, init_key, jax.random.fold_in(init_key, attempts)
    )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StepKeys:
  """A control step's keys, one per use."""

  before: jax.Array
  substep: jax.Array
  after: jax.Array
  obs: jax.Array
  next: jax.Array

  @classmethod
  def split(cls, key) -> 'StepKeys':
    return cls(*jax.random.split(key, 5))

  def of_substep(self, i) -> 'SubstepKeys':
    """The keys of sub-step `i`."""
    return SubstepKeys(jax.random.fold_in(self.substep, i))


@dataclasses.dataclass(frozen=True)
class SubstepKeys:
  """One sub-step's keys, each folded in where it is used."""

  key: jax.Array

  def before(self) -> jax.Array:
    """The `before_substep` hooks' key."""
    return jax.random.fold_in(self.key, 0)

  def after(self) -> jax.Array:
    """The `after_substep` hooks' key."""
    return jax.random.fold_in(self.key, 1)

  def obs(self) -> jax.Array:
    """The sub-step's observation update's key."""
    return jax.random.fold_in(self.key, 2)


def _select_key(pred, on_true, on_false):
  data = jnp.where(
      pred, jax.random.key_data(on_true), jax.random.key_data(on_false)
  )
  return jax.random.wrap_key_data(data, impl=jax.random.key_impl(on_true))
