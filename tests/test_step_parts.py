"""benchmarks/step_parts.py removes what each ablation names (traced only)."""

import os
import sys

import jax

sys.path.insert(
    0, os.path.join(os.path.dirname(os.path.dirname(__file__)), 'benchmarks')
)
import common  # pylint: disable=g-import-not-at-top,wrong-import-position
import step_parts  # pylint: disable=g-import-not-at-top,wrong-import-position


def _equations(jaxpr):
  """Equations of a jaxpr and of every jaxpr nested in it."""
  count = 0
  for eqn in jaxpr.eqns:
    count += 1
    for param in eqn.params.values():
      for sub in param if isinstance(param, (tuple, list)) else (param,):
        inner = getattr(sub, 'jaxpr', sub)
        if hasattr(inner, 'eqns'):
          count += _equations(inner)
  return count


def test_each_ablation_removes_a_part_and_keeps_the_physics():
  env = step_parts.make_env('reach')
  worlds = 2
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), worlds)
  )
  actions = common.random_actions(env, worlds)
  sizes, text = {}, {}
  for name in step_parts.PROGRAMS:
    fn, patches = step_parts.make_program(name, env, steps=1)
    start = states.data if name == 'raw' else states
    with step_parts.patched(**patches):
      jaxpr = jax.make_jaxpr(fn)(start, actions)
    sizes[name], text[name] = _equations(jaxpr.jaxpr), str(jaxpr)
  order = ('step', 'no_autoreset', 'no_end_step', 'no_substep')
  for bigger, smaller in zip(order, order[1:]):
    assert sizes[bigger] > sizes[smaller], sizes
  assert sizes['raw_in_state'] < sizes['no_substep'], sizes
  for name in step_parts.PROGRAMS:  # every program steps the physics
    assert 'solve' in text[name], name
  # The patches are undone: the environment steps as before.
  fn, _ = step_parts.make_program('step', env, steps=1)
  assert _equations(jax.make_jaxpr(fn)(states, actions).jaxpr) == sizes['step']
