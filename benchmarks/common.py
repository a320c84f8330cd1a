"""Setup shared by the benchmarks in this folder.

Building the registered tasks' environments (`TASKS`, from
`mjx_composer.suite.tasks.registry`), the raw MJX baseline on the same
compiled model, timing jitted calls, common command-line flags and writing
results as JSON. The benchmark scripts import it as `common` (Python puts
the script's folder, `benchmarks/`, on `sys.path`), so they run from a
checkout with the package installed or on `PYTHONPATH`:

    PYTHONPATH=. python benchmarks/throughput.py --worlds 1024
"""

import argparse
import glob
import gzip
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer.suite.tasks import registry

# The registered tasks (the bundled ones: `registry.names()`).
TASKS = registry.names()


# -- environments ------------------------------------------------------------


def make_env(
    name='reach',
    *,
    time_limit=2.0,
    episode_steps=None,
    observables=True,
    auto_reset='same_step',
    max_reset_attempts=None,
    share_reset_forward=None,
    auto_reset_batch='auto',
    impl='jax',
    naconmax=None,
    njmax=None,
    reset_forward=None,
    substep_sensors=None,
    branches=None,
    **task_kwargs,
):
  """A bundled task's `Environment`, as the benchmarks build it.

  Args:
    name: a registered task (`TASKS`).
    time_limit: episode length in seconds.
    episode_steps: if given, the episode length in control steps instead.
    observables: False disables every observable (no observation groups).
    auto_reset: the `Environment`'s auto-reset mode.
    max_reset_attempts: passed to the `Environment` when given.
    share_reset_forward: passed to the `Environment` when given.
    auto_reset_batch: the `Environment`'s `ExecutionOptions` field.
    reset_forward, substep_sensors, branches: `ExecutionOptions` fields,
      passed when given.
    impl, naconmax, njmax: the physics implementation ('jax', 'warp', or
      None for the `Environment`'s default) and MuJoCo Warp's buffer sizes,
      passed to the `Environment` when given. The benchmarks measure MJX's
      JAX implementation unless they say otherwise: `impl` is 'jax' by
      default, not the `Environment`'s default (Warp on a CUDA GPU).
    **task_kwargs: passed to the task's factory, over its registered
      kwargs (e.g. `randomize=False` for reach, `placement='ring'` for
      push).

  Returns:
    The `mjx_composer.Environment`, with the task's observation groups
    (policy/critic) when `observables` is True.
  """
  from mjx_composer import environment  # pylint: disable=g-import-not-at-top

  task = registry.make_task(name, **task_kwargs)
  if not observables:
    for obs in task.observables.values():
      obs.enabled = False
    task.observation_groups = lambda: None  # one dict of (no) observables
  if episode_steps is not None:
    time_limit = episode_steps * task.control_timestep
  kwargs = {}
  if max_reset_attempts is not None:
    kwargs['max_reset_attempts'] = max_reset_attempts
  options = {}
  if reset_forward is not None:
    options['reset_forward'] = reset_forward
  if substep_sensors is not None:
    options['substep_sensors'] = substep_sensors
  if branches is not None:
    options['branches'] = branches
  return environment.Environment(
      task,
      time_limit=time_limit,
      options=environment.ExecutionOptions(
          auto_reset=auto_reset,
          share_reset_forward=share_reset_forward,
          auto_reset_batch=auto_reset_batch,
          impl=impl,
          naconmax=naconmax,
          njmax=njmax,
          **options,
      ),
      **kwargs,
  )


def make_walk_like_playground(time_limit, **env_kwargs):
  """The walk task as Playground's HumanoidWalk: additions off, 'policy' only.

  `walk.PLAYGROUND_EQUIVALENT` (no noise, latency, history, randomization,
  pushes or fall terminations) observing only the 'policy' group, which is
  then HumanoidWalk's observation; same-step auto-reset. `env_kwargs` go to
  the `Environment` (e.g. `share_reset_forward`).
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer import environment
  from mjx_composer.suite.tasks import walk

  # pylint: enable=g-import-not-at-top
  task = walk.Walk(**walk.PLAYGROUND_EQUIVALENT)
  policy_only = {'policy': task.observation_groups()['policy']}
  task.observation_groups = lambda: policy_only
  return environment.Environment(
      task,
      time_limit=time_limit,
      options=environment.ExecutionOptions(
          auto_reset='same_step', **env_kwargs
      ),
  )


def random_actions(env, worlds, seed=1):
  """`(worlds,) + action shape` uniform actions in [-1, 1]."""
  spec = env.action_spec()
  return jax.random.uniform(
      jax.random.key(seed), (worlds,) + spec.shape, minval=-1.0, maxval=1.0
  )


# -- programs: composed and raw MJX -----------------------------------------


def env_rollout(env, steps, jit=True):
  """`rollout(states, actions) -> (states, actions)`: `steps` batched steps.

  `jax.lax.scan` over `jax.vmap(env.step)`, the actions held fixed.
  """
  vstep = jax.vmap(env.step)

  def rollout(states, actions):
    def control_step(s, _):
      return vstep(s, actions), None

    return jax.lax.scan(control_step, states, None, length=steps)[0], actions

  return jax.jit(rollout) if jit else rollout


def raw_rollout(model, n_sub_steps, steps, jit=True):
  """Raw MJX's `rollout(data, ctrl) -> (data, ctrl)` on a batch of worlds.

  `steps` control steps (`jax.lax.scan`), each setting `ctrl` and running
  `n_sub_steps` of `jax.vmap(mjx.step)` in a `jax.lax.fori_loop`.
  """
  step = jax.vmap(lambda d: mjx.step(model, d))

  def rollout(data, ctrl):
    def control_step(d, _):
      d = d.replace(ctrl=ctrl)
      d = jax.lax.fori_loop(0, n_sub_steps, lambda _, x: step(x), d)
      return d, None

    return jax.lax.scan(control_step, data, None, length=steps)[0], ctrl

  return jax.jit(rollout) if jit else rollout


def raw_reset(model, noise=0.01, jit=True, qpos=None):
  """Raw MJX's batched reset: `reset(keys) -> data`.

  Per world: `mjx.make_data`, `qpos` (None: the model's `qpos0`) plus
  `noise` x a standard normal sample from the world's key (so that the
  worlds differ and XLA cannot fold the reset into a constant), then
  `mjx.forward`.
  """

  def reset_one(key):
    data = mjx.make_data(model)
    start = data.qpos if qpos is None else jnp.asarray(qpos, data.qpos.dtype)
    noisy = start + noise * jax.random.normal(key, data.qpos.shape)
    return mjx.forward(model, data.replace(qpos=noisy))

  reset = jax.vmap(reset_one)
  return jax.jit(reset) if jit else reset


def raw_data(model, worlds):
  """A batch of `worlds` identical raw MJX data, after `mjx.forward`."""
  data = jax.vmap(lambda _: mjx.make_data(model))(jnp.arange(worlds))
  return jax.jit(jax.vmap(lambda d: mjx.forward(model, d)))(data)


# -- timing ------------------------------------------------------------------


def time_fn(fn, args, repeats):
  """Median seconds of `fn(*out)`, each call fed the previous call's outputs.

  For functions returning their own next arguments (rollouts). Two calls
  first: to compile, and because outputs may retrace once (dtypes).
  """
  out = jax.block_until_ready(fn(*args))  # compile + warm up
  out = jax.block_until_ready(fn(*out))  # outputs may retrace once (dtypes)
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*out))
    times.append(time.perf_counter() - t0)
  return statistics.median(times)


def time_calls(fn, make_args, repeats):
  """(first-call seconds, median seconds of `repeats` further calls).

  Call `i` gets `make_args(i)` (made and ready before the clock starts); the
  first call, `make_args(0)`, includes compilation.
  """
  t0 = time.perf_counter()
  out = jax.block_until_ready(fn(*make_args(0)))
  first = time.perf_counter() - t0
  times = []
  for i in range(repeats):
    args = jax.block_until_ready(make_args(i + 1))
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    times.append(time.perf_counter() - t0)
  del out
  return first, statistics.median(times)


# -- profiles ----------------------------------------------------------------


def perfetto_events(trace_dir):
  """The events of the newest Perfetto trace under `trace_dir`.

  As `jax.profiler.trace(trace_dir, create_perfetto_trace=True)` writes it.
  """
  paths = glob.glob(
      os.path.join(trace_dir, '**', 'perfetto_trace.json.gz'), recursive=True
  )
  if not paths:
    raise RuntimeError(f'No Perfetto trace under {trace_dir}.')
  with gzip.open(max(paths, key=os.path.getmtime), 'rt') as f:
    trace = json.load(f)
  return trace['traceEvents'] if isinstance(trace, dict) else trace


def metadata_names(events, kind):
  """`{id: name}` of a trace's `kind` metadata ('process_name': by pid,
  'thread_name': by (pid, tid))."""
  return {
      (e['pid'] if kind == 'process_name' else (e['pid'], e['tid'])): str(
          e.get('args', {}).get('name', '')
      )
      for e in events
      if e.get('ph') == 'M' and e.get('name') == kind
  }


# -- command line and results ------------------------------------------------


def default_out(filename):
  """`$OUT/filename`, or `./filename` when `OUT` is unset."""
  return os.path.join(os.environ.get('OUT', '.'), filename)


def add_worlds_arg(parser, default):
  parser.add_argument('--worlds', type=int, nargs='+', default=list(default))


def add_repeats_arg(parser, default):
  parser.add_argument('--repeats', type=int, default=default)


def add_out_arg(parser, filename):
  parser.add_argument('--out', default=default_out(filename))


def add_share_reset_forward_arg(parser):
  """`--share-reset-forward on|off`, read back by `share_reset_forward`."""
  parser.add_argument(
      '--share-reset-forward',
      choices=('on', 'off'),
      default=None,
      help="our environments' ExecutionOptions(share_reset_forward=...) "
      "(default: the Environment's default for the device)",
  )


def share_reset_forward(args):
  """`--share-reset-forward` as the `Environment` takes it (None: default)."""
  if args.share_reset_forward is None:
    return None
  return args.share_reset_forward == 'on'


def make_parser(doc, *, worlds=None, repeats=None, out=None):
  """An `ArgumentParser` described by `doc`'s first line, with shared flags.

  Args:
    doc: the script's docstring.
    worlds: default `--worlds` (a list); no flag when None.
    repeats: default `--repeats`; no flag when None.
    out: default file name of `--out` (in `$OUT`); no flag when None.
  """
  parser = argparse.ArgumentParser(description=doc.splitlines()[0])
  if worlds is not None:
    add_worlds_arg(parser, worlds)
  if repeats is not None:
    add_repeats_arg(parser, repeats)
  if out is not None:
    add_out_arg(parser, out)
  return parser


def print_device():
  """Prints and returns the default JAX device."""
  device = jax.devices()[0]
  print(f'JAX {jax.__version__}, {device.platform}: {device.device_kind}')
  return device


def run_isolated(script, argv):
  """Runs `script` with `argv` in a fresh Python process; its JSON or None.

  For `--isolated` measurements: the script is given `--out` (a temporary
  file) after `argv` and must write its results there, as `write_results`
  does. Returns the payload it wrote, or None if the process failed (its
  output, not captured, says why).
  """
  with tempfile.TemporaryDirectory() as tmp:
    out = os.path.join(tmp, 'results.json')
    command = [sys.executable, os.path.abspath(script), *argv, '--out', out]
    if subprocess.run(command, check=False).returncode:
      return None
    with open(out) as f:
      return json.load(f)


def write_results(path, device, results, **settings):
  """Writes a benchmark's `results` with the device, JAX version and settings."""
  write_json(
      path,
      {
          'device': device.device_kind,
          'jax': jax.__version__,
          **settings,
          'results': results,
      },
  )


def write_json(path, payload):
  """Writes `payload` as indented JSON, creating `path`'s folder."""
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  with open(path, 'w') as f:
    json.dump(payload, f, indent=2)


def print_ratio_table(results):
  """Prints `results` (rows of `worlds`, `raw` and programs' physics steps
  per second) as a Markdown table of each program's ratio to `raw`."""
  names = [k for k in results[0] if k not in ('worlds', 'raw')]
  print('\n| worlds | raw MJX (physics steps/s) | ' + ' | '.join(names) + ' |')
  print('|---|---|' + '---|' * len(names))
  for r in results:
    print(
        f'| {r["worlds"]:,} | {r["raw"] / 1e6:.2f} M | '
        + ' | '.join(f'{r[k] / r["raw"]:.3f}' for k in names)
        + ' |'
    )
