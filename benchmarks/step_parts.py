"""What each part of the composed step costs, by taking parts away.

`overhead.py` compares the whole step with raw MJX; this finds which part
of the difference each piece of the step holds. On the bundled reach task
(or, with `--task walk`, the walk task with its additions off,
`walk.PLAYGROUND_EQUIVALENT`; no time limit, so no world ever resets,
domain randomization off), every
program starts from the same reset states and holds the same actions:

* raw:           raw MJX (`common.raw_rollout`) on the states' `mjx.Data`;
* step:          `vmap(env.step)`, the whole composed step;
* no_autoreset:  the step without its auto-reset (`Transitions.step`: the
                 `lax.cond` on whether any world's episode ended is gone);
* no_end_step:   `no_autoreset` without the control step's end (the
                 `after_step` hooks, the observation update, reward,
                 discount and episode rules): the state keeps its
                 observation and episode fields;
* no_substep:    `no_end_step` without the per-sub-step work (the sub-step
                 hooks, their keys and the observation updates between
                 sub-steps): the scan runs `mjx.step` alone;
* raw_in_state:  raw MJX's control step on the `State`'s `mjx.Data`, the
                 rest of the `State` carried along unchanged: what carrying
                 the composed state through the rollout costs.

Each removal is a monkeypatch of `transitions.Transitions` in force while
that program is traced; none is a supported configuration. Physics steps
per second, median of `--repeats` calls of `--steps` control steps, and
each ratio to `raw` of the same run.

    python benchmarks/step_parts.py --worlds 8192 32768
"""

import contextlib

import jax
from mujoco import mjx

from mjx_composer import transitions

import common  # benchmarks/common.py

PROGRAMS = (
    'raw',
    'step',
    'no_autoreset',
    'no_end_step',
    'no_substep',
    'raw_in_state',
)


def _end_step_kept(self, state, physics, obs_state, keys):
  """`_end_step` reduced to carrying the new physics and keys."""
  del self
  return state.replace(
      data=physics.data,
      task_state=physics.task_state,
      obs_state=obs_state,
      key=keys.next,
  )


def _before_substep_none(self, physics, action, keys, i, fields):
  del self, action, keys, i, fields
  return physics


def _after_substep_none(self, physics, obs_state, keys, i, fields):
  del self, keys, i
  return physics.carry(fields), obs_state


@contextlib.contextmanager
def patched(**methods):
  cls = transitions.Transitions
  saved = {name: getattr(cls, name) for name in methods}
  for name, method in methods.items():
    setattr(cls, name, method)
  try:
    yield
  finally:
    for name, method in saved.items():
      setattr(cls, name, method)


_PATCHES = {
    'no_end_step': dict(_end_step=_end_step_kept),
    'no_substep': dict(
        _end_step=_end_step_kept,
        _before_substep=_before_substep_none,
        _after_substep=_after_substep_none,
    ),
}


def state_rollout(env, steps):
  """`raw_in_state`: raw MJX's control step on `State.data`."""
  step = jax.vmap(lambda d: mjx.step(env.mjx_model, d))
  n = env.n_sub_steps

  def rollout(states, actions):
    def control_step(s, _):
      d = s.data.replace(ctrl=actions)
      d = jax.lax.fori_loop(0, n, lambda _, x: step(x), d)
      return s.replace(data=d), None

    return jax.lax.scan(control_step, states, None, length=steps)[0], actions

  return jax.jit(rollout)


def _transitions_rollout(env, steps):
  """`scan` over `vmap(Transitions.step)`: the step without auto-reset."""
  vstep = jax.vmap(env._transitions.step)  # pylint: disable=protected-access

  def rollout(states, actions):
    def control_step(s, _):
      return vstep(s, actions), None

    return jax.lax.scan(control_step, states, None, length=steps)[0], actions

  return jax.jit(rollout)


def make_env(task='reach'):
  """The task without episode ends or randomization (see above)."""
  if task == 'walk':
    from mjx_composer.tasks import walk  # pylint: disable=g-import-not-at-top

    return common.make_env(
        'walk', **walk.PLAYGROUND_EQUIVALENT, time_limit=float('inf')
    )
  return common.make_env('reach', randomize=False, time_limit=float('inf'))


def make_program(name, env, steps):
  """`(rollout, patches)` of program `name`: `rollout(start, actions)`.

  `start` is a batch of `State`s, or its `mjx.Data` for 'raw'; trace
  `rollout` within `patched(patches)`.
  """
  n = env.n_sub_steps
  patches = _PATCHES.get(name, {})
  if name == 'raw':
    return common.raw_rollout(env.mjx_model, n, steps), patches
  if name == 'step':
    return common.env_rollout(env, steps), patches
  if name == 'raw_in_state':
    return state_rollout(env, steps), patches
  return _transitions_rollout(env, steps), patches


def main():
  parser = common.make_parser(
      __doc__, worlds=[8192], repeats=3, out='step_parts.json'
  )
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  parser.add_argument(
      '--programs', nargs='+', default=list(PROGRAMS), choices=PROGRAMS
  )
  parser.add_argument(
      '--task',
      default='reach',
      choices=('reach', 'walk'),
      help='walk: `walk.PLAYGROUND_EQUIVALENT` (its additions off)',
  )
  args = parser.parse_args()
  device = common.print_device()
  env = make_env(args.task)
  n = env.n_sub_steps
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds}
    results.append(row)
    actions = common.random_actions(env, worlds)
    keys = jax.random.split(jax.random.key(0), worlds)
    states = jax.jit(jax.vmap(env.reset))(keys)
    for name in dict.fromkeys(('raw', *args.programs)):
      fn, patches = make_program(name, env, args.steps)
      start = states.data if name == 'raw' else states
      with patched(**patches):
        seconds = common.time_fn(fn, (start, actions), args.repeats)
      row[name] = worlds * args.steps * n / seconds
      print(f'{worlds:>7} worlds: {name} {row[name]:,.0f}', flush=True)
      common.write_results(
          args.out, device, results, n_sub_steps=n, steps_per_call=args.steps
      )

  common.print_ratio_table(results)


if __name__ == '__main__':
  main()
