"""What the locomotion kit costs: the Go1 and the humanoid on generated terrain.

In one process, on one device, for each number of worlds, these programs
step their robot for `--steps` control steps, one random action per world
held for the whole call:

* raw:        `jax.lax.scan` over control steps of `n_sub_steps` x
              `jax.vmap(mjx.step)` (`common.raw_rollout`) on
              joystick_terrain's compiled model (the generated terrain's
              height field, the Go1), the actions as controls, from `qpos0`
              with the Go1's free joint moved onto the first tile's spawn
              platform (level 0, the first kind), plus noise;
* joystick:   the flat-ground `joystick.Joystick()` (a plane);
* joystick_terrain: `joystick_terrain.TerrainJoystick()` as registered:
              generated terrain (every sub-terrain kind, 5 levels of 4 m
              tiles, one height field) with its curriculum, the Go1's feet
              its only terrain contacts, the height scan in the policy's
              observation (and its clean twin in the critic's), velocity
              commands, actuation delay of U{0, 2} sub-steps;
* joystick_terrain_no_scan: the same with `height_scan=False` (neither
              group observes a scan; no rays are cast);
* joystick_terrain_off: the same task with every part switched off as far
              as its constructor allows: `kinds=('flat',)` and `levels=1`
              (one flat 4 m tile), `initial_levels=(0, 0)`,
              `actuation_delay=(0, 0)` and `height_scan=False`;
* walk:       the flat-ground humanoid `walk.Walk()`;
* walk_terrain: `walk_terrain.TerrainWalk()` as registered (its terrain,
              curriculum and height scan; the humanoid's feet its only
              terrain contacts).

The composed programs are `vmap(env.step)` in a `jax.lax.scan`
(`common.env_rollout`) with same-step auto-reset and the tasks' defaults
otherwise (noise, observation delay and history, per-episode
randomization, pushes, falls ending episodes): worlds that fall reset
inside the call, raw's never do. Episodes last as long as the tasks train
on (their registry entries' `time_limit`: 20 s for the Go1, 25 s for the
humanoid).

For each: control and physics steps per second (median of `--repeats`
calls), the first calls (trace, lowering and XLA compile of the batched
reset, and of the rollout; the rollout's first call with its first run;
`playground_compare.measure`) and the bytes of one world's state; ratios
to raw and to the program's flat-ground twin (`FLAT`); and the height
scan's cost per world: joystick_terrain's time per world and control step
less joystick_terrain_no_scan's, and the difference of their state bytes.

The process compiles a trivial function before the first program, so that
the backend's start-up is in no program's first call. With `--isolated`
each program at each number of worlds runs in a fresh process of this
script (`common.run_isolated`), so that no program's first call profits
from another's compiles; the ratios then divide figures from different
processes.

    python benchmarks/locomotion_parts.py --worlds 4096 16384
    python benchmarks/locomotion_parts.py --worlds 4 --steps 2   # smoke
    python benchmarks/locomotion_parts.py --isolated --worlds 8192 \\
        --programs raw joystick joystick_terrain
"""

import jax
import mujoco
import numpy as np

from mjx_composer.platform import cpu_linalg
from mjx_composer.suite.tasks import registry

import common  # benchmarks/common.py
import playground_compare  # benchmarks/playground_compare.py: measure

# TerrainJoystick's arguments of joystick_terrain_off.
PARTS_OFF = dict(
    kinds=('flat',),
    levels=1,
    initial_levels=(0, 0),
    actuation_delay=(0, 0),
    height_scan=False,
)
# The composed programs: the registered task each builds, and the arguments
# its factory gets over the registered ones.
TASKS = {
    'joystick': ('joystick', {}),
    'joystick_terrain': ('joystick_terrain', {}),
    'joystick_terrain_no_scan': ('joystick_terrain', dict(height_scan=False)),
    'joystick_terrain_off': ('joystick_terrain', PARTS_OFF),
    'walk': ('walk', {}),
    'walk_terrain': ('walk_terrain', {}),
}
# Each program's flat-ground twin (the ratio '/flat').
FLAT = {
    'raw': 'joystick',
    'joystick_terrain': 'joystick',
    'joystick_terrain_no_scan': 'joystick',
    'joystick_terrain_off': 'joystick',
    'walk_terrain': 'walk',
}
PROGRAMS = ('raw', *TASKS)


def make_envs(names, share_reset_forward=None):
  """The environments of the composed programs in `names` (and
  joystick_terrain's, whose compiled model raw steps, when raw is among
  them)."""
  wanted = set(names) - {'raw'}
  if 'raw' in names:
    wanted.add('joystick_terrain')
  envs = {}
  for name in TASKS:
    if name in wanted:
      task, kwargs = TASKS[name]
      envs[name] = common.make_env(
          task,
          time_limit=registry.entry(task).training['time_limit'],
          share_reset_forward=share_reset_forward,
          **kwargs,
      )
  return envs


def raw_start(env):
  """`qpos0` of `env`'s model with its one free joint on a spawn platform.

  The first tile's (level 0, the first kind): `qpos0`'s origin lies on
  whichever sub-terrain covers the middle of the grid, which may cut
  through the robot.
  """
  model = env.mj_model
  (free,) = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
  adr = model.jnt_qposadr[free]
  qpos = np.array(model.qpos0, np.float32)
  spawn = env.task.terrain.spawn_points[0, 0]
  qpos[adr : adr + 3] = spawn + [0.0, 0.0, env.task.go1.home_height + 0.01]
  return qpos


def derive(row, steps):
  """Adds ratios and the height scan's cost to a row of measured programs."""
  for name in PROGRAMS:
    for other, key in (('raw', 'raw'), (FLAT.get(name), 'flat')):
      if name != other and name in row and other in row:
        row[f'{name}/{key}'] = (
            row[name]['control_steps_per_s'] / row[other]['control_steps_per_s']
        )
        row[f'{name}/{key}_state'] = (
            row[name]['state_bytes_per_world']
            / row[other]['state_bytes_per_world']
        )
  on, off = row.get('joystick_terrain'), row.get('joystick_terrain_no_scan')
  if on and off:
    world_steps = row['worlds'] * steps
    row['height_scan'] = {
        'seconds_per_world_step': (
            on['seconds_per_call'] - off['seconds_per_call']
        )
        / world_steps,
        'throughput_ratio': (
            on['control_steps_per_s'] / off['control_steps_per_s']
        ),
        'state_bytes_per_world': (
            on['state_bytes_per_world'] - off['state_bytes_per_world']
        ),
        'rollout_compile_s': on['rollout_compile_s'] - off['rollout_compile_s'],
    }


def print_table(results):
  print(
      '\n| worlds | program | control steps/s | physics steps/s | / raw '
      '| / flat | reset compile (s) | rollout compile (s) '
      '| rollout first call (s) | state (KiB/world) | state / flat |'
  )
  print('|---|---|---|---|---|---|---|---|---|---|---|')
  ratio = lambda r, key: f'{r[key]:.3f}' if key in r else '-'
  for row in results:
    for name in PROGRAMS:
      if name not in row:
        continue
      m = row[name]
      print(
          f'| {row["worlds"]:,} | {name} | {m["control_steps_per_s"]:,.0f} '
          f'| {m["physics_steps_per_s"]:,.0f} | {ratio(row, f"{name}/raw")} '
          f'| {ratio(row, f"{name}/flat")} | {m["reset_compile_s"]:.1f} '
          f'| {m["rollout_compile_s"]:.1f} | {m["first_call_s"]:.1f} '
          f'| {m["state_bytes_per_world"] / 1024:.1f} '
          f'| {ratio(row, f"{name}/flat_state")} |'
      )
  for row in results:
    scan = row.get('height_scan')
    if scan:
      print(
          f'\nHeight scan, {row["worlds"]:,} worlds: '
          f'{scan["seconds_per_world_step"] * 1e9:,.0f} ns per world and '
          f'control step, throughput x{scan["throughput_ratio"]:.3f}, '
          f'{scan["state_bytes_per_world"]:+,.0f} state bytes per world, '
          f'rollout compile {scan["rollout_compile_s"]:+.1f} s '
          '(joystick_terrain against joystick_terrain_no_scan).'
      )


def _settings(args, envs=None):
  settings = dict(
      steps_per_call=args.steps,
      repeats=args.repeats,
      parts_off=repr(PARTS_OFF),
      note=(
          'Every program holds one random action per world. The composed '
          'programs reset worlds whose robot falls (same-step auto-reset); '
          'raw never resets within a call.'
      ),
  )
  if envs:
    settings.update(
        sub_steps={name: env.n_sub_steps for name, env in envs.items()},
        share_reset_forward=next(iter(envs.values())).share_reset_forward,
    )
  return settings


def main_isolated(args, names):
  """`--isolated`: every (worlds, program) in its own process.

  This process never starts JAX's backend: on a GPU it would hold the
  memory the workers need.
  """
  results, settings = [], {}
  for worlds in args.worlds:
    row = {'worlds': worlds}
    results.append(row)
    for name in names:
      argv = ['--worlds', str(worlds), '--programs', name]
      argv += ['--steps', str(args.steps), '--repeats', str(args.repeats)]
      if args.share_reset_forward is not None:
        argv += ['--share-reset-forward', args.share_reset_forward]
      payload = common.run_isolated(__file__, argv)
      if payload is None:
        print(f'{worlds:>6} worlds: {name} failed (its output says why)')
        continue
      row[name] = payload['results'][0][name]
      settings = {k: v for k, v in payload.items() if k != 'results'}
      derive(row, args.steps)
      common.write_json(
          args.out, {**settings, 'isolated': True, 'results': results}
      )
  print_table(results)
  print(f'Wrote {args.out}')


def main():
  parser = common.make_parser(
      __doc__, worlds=[4096, 16384], repeats=3, out='locomotion_parts.json'
  )
  parser.add_argument(
      '--steps', type=int, default=100, help='control steps per timed call'
  )
  parser.add_argument(
      '--programs',
      nargs='+',
      choices=PROGRAMS,
      default=list(PROGRAMS),
      help='measure only these (default: all)',
  )
  parser.add_argument(
      '--isolated',
      action='store_true',
      help='measure each program at each number of worlds in a fresh '
      'process (first calls profit from no other compile; the ratios then '
      'divide numbers from different processes)',
  )
  common.add_share_reset_forward_arg(parser)
  args = parser.parse_args()
  names = [n for n in PROGRAMS if n in args.programs]
  if args.isolated:
    return main_isolated(args, names)

  cpu_linalg.enable()  # before compiling: see its module docstring
  device = common.print_device()
  # The backend's one-time start-up, so the first program measured does not
  # pay it in its first call.
  jax.block_until_ready(jax.jit(lambda x: x + 1)(np.float32(0)))
  envs = make_envs(names, common.share_reset_forward(args))
  settings = _settings(args, envs)
  results = []
  for worlds in args.worlds:
    keys = jax.random.split(jax.random.key(0), worlds)
    row = {'worlds': worlds}
    results.append(row)
    for name in names:
      if name == 'raw':
        env = envs['joystick_terrain']
        model = env.mjx_model
        reset = common.raw_reset(model, jit=False, qpos=raw_start(env))
        rollout = common.raw_rollout(
            model, env.n_sub_steps, args.steps, jit=False
        )
      else:
        env = envs[name]
        reset = jax.vmap(env.reset)
        rollout = common.env_rollout(env, args.steps, jit=False)
      actions = common.random_actions(env, worlds)
      measured = playground_compare.measure(
          reset, rollout, keys, actions, args.repeats, device
      )
      per_s = worlds * args.steps / measured['seconds_per_call']
      measured['control_steps_per_s'] = per_s
      measured['physics_steps_per_s'] = per_s * env.n_sub_steps
      row[name] = measured
      derive(row, args.steps)
      print(
          f'{worlds:>6} worlds: {name} {per_s:,.0f} control steps/s, '
          f'reset compile {measured["reset_compile_s"]:.1f} s, '
          f'rollout first call {measured["first_call_s"]:.1f} s',
          flush=True,
      )
      # Written after every program: a run cut short keeps what it measured.
      common.write_results(args.out, device, results, **settings)
  print_table(results)
  print(f'Wrote {args.out}')


if __name__ == '__main__':
  main()
