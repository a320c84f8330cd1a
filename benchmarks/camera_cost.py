"""What a ray-cast camera observable costs in a step, against none.

The reach task (randomization off, 2 s episodes, same-step auto-reset, its
observables in one dict) with one `observable.MujocoCamera('overview', S,
S, ...)` of its arena added to the task's observables, for each `--sizes`
S (pixels a side; 0: no camera). Each program is `--steps` control steps of
`vmap(env.step)` in a `lax.scan` over `--worlds` worlds, timed as the median
of `--repeats` calls (`common.time_fn`). Prints control steps per second,
the ratio to no camera, and the first call's seconds (compile included).

    python benchmarks/camera_cost.py --worlds 8 --sizes 0 16 32 --kind depth
"""

import time

import jax

from mjx_composer import environment
from mjx_composer.observation import observable
from mjx_composer.tasks import reach

import common  # benchmarks/common.py

_KINDS = {
    'rgb': {},
    'depth': {'depth': True},
    'segmentation': {'segmentation': True},
}


class _ReachWithCamera(reach.Reach):
  """Reach with one camera image among its task observables."""

  def __init__(self, size, kind):
    super().__init__(randomize=False)
    self._camera = None
    if size:
      self._camera = observable.MujocoCamera(
          'overview', size, size, **_KINDS[kind]
      )
      self._camera.enabled = True

  @property
  def task_observables(self):
    observables = dict(super().task_observables)
    if self._camera is not None:
      observables['camera'] = self._camera
    return observables


def make_env(size, kind):
  return environment.Environment(
      _ReachWithCamera(size, kind),
      time_limit=2.0,
      auto_reset='same_step',
      observation_groups={},  # one dict: the image is observed
      impl='jax',
  )


def main():
  parser = common.make_parser(
      __doc__, worlds=[8], repeats=3, out='camera_cost.json'
  )
  parser.add_argument('--sizes', type=int, nargs='+', default=[0, 16, 32])
  parser.add_argument('--kind', choices=sorted(_KINDS), default='depth')
  parser.add_argument('--steps', type=int, default=10)
  args = parser.parse_args()
  device = common.print_device()
  results = []
  for worlds in args.worlds:
    for size in args.sizes:
      env = make_env(size, args.kind)
      keys = jax.random.split(jax.random.key(0), worlds)
      states = jax.jit(jax.vmap(env.reset))(keys)
      rollout = common.env_rollout(env, args.steps)
      actions = common.random_actions(env, worlds)
      start = time.perf_counter()
      jax.block_until_ready(rollout(states, actions))
      first_call = time.perf_counter() - start
      seconds = common.time_fn(rollout, (states, actions), args.repeats)
      row = {
          'worlds': worlds,
          'size': size,
          'kind': args.kind,
          'control_steps_per_s': worlds * args.steps / seconds,
          'first_call_s': first_call,
      }
      base = [
          r
          for r in results
          if r['worlds'] == worlds and r['size'] == 0 and r['kind'] == args.kind
      ]
      if base:
        row['ratio_to_no_camera'] = (
            row['control_steps_per_s'] / base[0]['control_steps_per_s']
        )
      results.append(row)
      print(
          f'{worlds:>6} worlds, {size:>3} px {args.kind}: '
          f"{row['control_steps_per_s']:,.0f} control steps/s"
          + (
              f" ({row['ratio_to_no_camera']:.3f} of none)"
              if 'ratio_to_no_camera' in row
              else ''
          )
          + f', first call {first_call:.1f} s',
          flush=True,
      )
      common.write_results(args.out, device, results, steps=args.steps)


if __name__ == '__main__':
  main()
