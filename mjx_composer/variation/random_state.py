"""composer's `random_state=` argument, refused with what to pass instead.

composer's variations draw from a shared numpy `RandomState` passed as
`random_state=`; here every draw is a pure function of a JAX PRNG key. A
ported call that still passes `random_state=` gets a `TypeError` that says
to pass `key=` (`reject`); `NO_RANDOM_STATE` is the default that tells the
argument was not passed.
"""


class _NoRandomState:
  """The default of `random_state=`: composer's argument was not passed."""

  def __repr__(self):
    return "NO_RANDOM_STATE"


NO_RANDOM_STATE = _NoRandomState()


def reject(random_state, where: str) -> None:
  """Raises a `TypeError` where composer's `random_state=` was passed.

  composer draws from a shared numpy `RandomState`; here every draw is a
  pure function of a JAX PRNG key, so a ported call must pass `key=`.

  Args:
    random_state: the value passed as `random_state=` (`NO_RANDOM_STATE`
      where none was).
    where: what was called, for the message.
  """
  if random_state is NO_RANDOM_STATE:
    return
  raise TypeError(
      f"{where} got random_state={random_state!r}: pass key=... instead, a "
      "JAX PRNG key (key=jax.random.key(seed)); a device hook "
      "(initialize_episode, the step hooks) passes on the key it receives. "
      "composer's numpy RandomState has no counterpart in a jitted, batched "
      "step: every draw is a pure function of its key. The build-time hooks "
      "(initialize_episode_mjcf, after_compile) receive no key: they run "
      "once, so a value drawn there would be the same in every world and "
      "episode. Bind the MJCF attribute to a variation.MJCFVariator (its "
      "apply_variations(random_state) there varies it every episode), or "
      "draw the value in initialize_episode."
  )
