"""`Initializer`: a reusable piece of episode initialization.

composer's initializers mutate a physics in place with a numpy random state.
Here an initializer is a pure function, `initializer(physics, key) ->
physics`, meant to be called from a task's (or entity's) `initialize_episode`
hook:

    def initialize_episode(self, physics, key):
      return self._prop_placer(physics, key)

Like every device hook it may not keep per-world state on `self`: state that
must outlive the call belongs in `physics.task_state` or in the physics'
persistent entries (`Physics.get_persistent`/`set_persistent`). An
initializer that cannot initialize the episode never raises inside jit: it
marks the episode with `physics.fail_initialization(...)`, and the
`Environment` resamples it with a fresh key, up to `max_reset_attempts`
times (composer's `EpisodeInitializationError`).
"""

import abc


class Initializer(metaclass=abc.ABCMeta):
  """The base class of initializers."""

  @abc.abstractmethod
  def __call__(self, physics, key):
    """Initializes one world's episode.

    Args:
      physics: the world's `Physics`.
      key: a JAX PRNG key for this call.

    Returns:
      The new `Physics`.
    """
