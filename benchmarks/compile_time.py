"""Trace, lowering and compile time, and program size: composed vs raw MJX.

For each bundled task (`--tasks`), on the task's compiled model, it measures
these programs, each jitted over a batch of `--worlds` worlds:

* reset:     `jax.vmap(env.reset)` on a batch of keys;
* step:      `jax.lax.scan` of `--steps` control steps over
             `jax.vmap(env.step)`, the environment built as the CLI and the
             training script build it: the task's per-episode randomization,
             its full observation set with the policy/critic groups, and
             `auto_reset='same_step'` (so the step program holds a reset);
* raw_reset: `jax.vmap` of raw MJX's reset: `mjx.make_data`, `qpos0` plus
             noise from the world's key, `mjx.forward`;
* raw_step:  `jax.lax.scan` of `--steps` control steps, each `n_sub_steps` of
             `jax.vmap(mjx.step)` in a `jax.lax.fori_loop`, as in
             `throughput.py`;
* with `--ppo`, ppo / raw_ppo: Brax's `ppo.train` for one training epoch of
  one training step (`num_evals=1`, evaluation off, tiny batch), on
  `BraxEnv(env)` and on a minimal Brax environment around the same raw MJX
  reset and step (Brax's own episode/auto-reset/vmap wrappers, observations
  `qpos, qvel`).

Timing. Each program is staged explicitly, `traced = jax.jit(f).trace(*args)`,
`lowered = traced.lower()`, `compiled = lowered.compile()`, and each stage is
timed on its own (JAX versions without `.trace` fall back to
`jax.jit(f).lower(*args)`, whose time then includes tracing). The arguments
of the step programs are abstract (`jax.eval_shape` of the reset), so nothing
but the measured program is compiled before it. PPO is timed end to end
(wall time of `ppo.train`, compilation included) and, program by program, with
JAX's own compile events (`jax.monitoring`: jaxpr trace, jaxpr to MLIR,
backend compile), summed over every program `ppo.train` compiles (in the
JSON, per program: trace times under the traced function's name, lowering
and compile times under the module's, e.g. `jit(_fun)` for Brax's pmapped
training epoch).

`--xla-phases` also records where XLA's compile time goes, from XLA's own
timers (which it prints where `TF_CPP_VMODULE` asks for them,
`XLA_TIMER_ENV`): `xla_hlo_passes_s`, its HLO optimization passes, and
`xla_backend_s`, its code generation (LLVM IR; on a GPU, also the PTX
assembled into kernels, on several threads), and `xla_passes`, its slowest
HLO passes with their seconds (`xla_passes()`; the ten slowest of each
program are printed). Each program then runs in its own process (not with
`--in-process`).

Threefry is lowered as JAX's GPU kernel (`prng_lowering.enable()`), as our
scripts compile; `MJX_COMPOSER_THREEFRY_KERNEL=0` measures without it.

JAX's persistent compilation cache is DISABLED here
(`jax_enable_compilation_cache=False`, whatever `JAX_COMPILATION_CACHE_DIR`
or `MJX_COMPOSER_CACHE_DIR` say), else compile times would be cache reads.
By default every program is measured in a fresh Python process, so that no
program profits from another's in-process caches (Python-level trace caches,
XLA's autotuning results on a GPU) and the order does not matter; each process
compiles a trivial function first, to keep one-time backend start-up costs out.
`--in-process` measures all in this process instead (faster, less fair).

Program size, per program:

* jaxpr_eqns: equations of the jaxpr, nested jaxprs (scan/while bodies, cond
  branches, inner jits) counted once per place they are used;
* stablehlo_ops: operations in the lowered StableHLO module (each outlined
  function once);
* hlo_instructions / hlo_while_loops: instructions and while loops of the
  optimized HLO XLA compiled (`compiled.as_text()`);
* mjx_step / mjx_forward / mjx_solve / mjx_fwd_position: how many copies of
  `mjx.step`, of the forward pass (`mjx.forward`, also the one inside each
  `mjx.step`), of the constraint solver and of the position stage are in the
  program, counted from MJX's named scopes in the jaxpr (a loop body counts
  once, however many times it runs);
* jaxpr_scopes: the jaxpr's equations per named scope path, four scopes
  deep ('initialize/apply_variations/model_compiler/set_const'),
  the 30 largest; `--scopes N` prints the N largest of every program.

Ratios composed / raw are reported for trace, compile and total (trace +
lowering + compile) time and for the sizes. Results go to `--out` as JSON,
rewritten after each program (a run cut short by a time limit keeps what it
measured; `unfinished` names the programs it had left), and to stdout as
tables, the ratios last.

Tasks are the bundled ones (`common.TASKS`), or a variant of the walk task
named as `benchmarks/playground_compare.py` names its programs, e.g.
`walk:ours_off` (Playground's HumanoidWalk equivalent) or `walk:only_push`
(that one feature on top of it), or `reach:fixed` / `push:fixed` (the task
with its per-episode randomization off). A variant's ratios divide by the raw
programs of its base task (the same compiled model), measured once, under the
base task, when it is among `--tasks`.

    python benchmarks/compile_time.py --tasks reach push --worlds 8
    PYTHONPATH=. python benchmarks/compile_time.py --ppo   # on a GPU machine
    python benchmarks/compile_time.py --tasks walk walk:ours_off \
        walk:only_randomize --programs step raw_step

`--share-reset-forward on|off` builds the composed environments with that
`ExecutionOptions(share_reset_forward=...)` (default: the device's default, on
for a CPU, off for a GPU), e.g. to compare the two step programs on a GPU;
`--branches loop|cond` with that `ExecutionOptions(branches=...)` (default:
'cond' on a CPU, 'loop' elsewhere), and `--reset-forward` likewise.
"""

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time

_PROGRAMS = ('raw_reset', 'reset', 'raw_step', 'step')
_PPO_PROGRAMS = ('raw_ppo', 'ppo')
# MJX's named scopes (mujoco/mjx/_src/forward.py) whose copies are counted,
# and the first scope each opens inside it (to split back-to-back copies).
_SCOPES = {
    'step': 'forward',
    'forward': 'fwd_position',
    'solve': None,
    'fwd_position': None,
}
_TIME_KEYS = ('trace_s', 'lower_s', 'compile_s', 'total_s')
_SIZE_KEYS = (
    'jaxpr_eqns',
    'stablehlo_ops',
    'hlo_instructions',
    'hlo_while_loops',
)


# XLA's own timers of the two phases of a compilation, which it prints to
# stderr where `TF_CPP_VMODULE` asks for them (`--xla-phases`): the HLO
# optimization passes, and the backend (LLVM IR, and on a GPU its PTX
# assembled into kernels). Patterns for XLA's GPU and CPU compilers.
XLA_TIMER_ENV = {
    'TF_CPP_MIN_LOG_LEVEL': '0',
    'TF_CPP_VMODULE': 'gpu_compiler=1,cpu_compiler=1,hlo_pass_pipeline=1',
}
_XLA_PHASE_KEYS = ('xla_hlo_passes_s', 'xla_backend_s')
_XLA_TIMERS = (
    ('xla_hlo_passes_s', r'GpuCompiler::RunHloPasses for (\S+) time: '),
    ('xla_backend_s', r'GpuCompiler::RunBackend for (\S+) time: '),
    ('xla_hlo_passes_s', r'Running HLO passes on \[(\S+)\] for CPU time: '),
    ('xla_backend_s', r'Compiling \[(\S+)\] for CPU using JIT time: '),
)
_XLA_UNITS = {'us': 1e-6, 'ms': 1e-3, 's': 1.0, 'min': 60.0, 'h': 3600.0}
# A timer's duration, '21.3 s': its value and its unit (`_XLA_UNITS`).
_DURATION = r'([\d.]+) (us|ms|s|min|h)\b'


def xla_phases(log: str, module: str) -> dict:
  """Seconds of each phase of compiling `module` ('jit_rollout'), read from
  XLA's timer lines in `log`; the longest where it compiled more than once
  (the measured program, not a small one of the same name). A phase whose
  line is missing is left out."""
  phases = {}
  for key, prefix in _XLA_TIMERS:
    pattern = re.compile(prefix + _DURATION)
    for m in pattern.finditer(log):
      if m.group(1) == module:
        seconds = float(m.group(2)) * _XLA_UNITS[m.group(3)]
        phases[key] = max(phases.get(key, 0.0), seconds)
  return phases


# XLA's timer of each HLO pass (`hlo_pass_pipeline=1`), and the line that
# opens each pipeline: 'I1130 04:31:08.39 32641 hlo_pass_pipeline.cc:303]
# Running HLO pass pipeline on module jit_rollout: simplification', then
# '... HLO pass: algsimp time: 8 us (8 us) ...' on the same thread.
_PASS_LOG = r'I\d{4} \S+\s+(\d+) hlo_pass_pipeline\.cc:\d+\] '  # its thread
_PIPELINE = re.compile(
    _PASS_LOG + r'Running HLO pass pipeline on module (\S+): (.*)$'
)
_PASS = re.compile(_PASS_LOG + r'HLO pass: (\S+) time: ' + _DURATION)
XLA_PASS_ROWS = 20  # passes kept per program in the JSON


def xla_passes(log: str, module: str, n: int = XLA_PASS_ROWS) -> dict:
  """XLA's `n` slowest HLO passes compiling `module`, in seconds, from the
  pass timers in `log`: `{'<pipeline>: <pass>': seconds}`, slowest first,
  each pass's time summed over its runs in that pipeline (a pipeline that
  runs passes to a fixed point runs them many times). A pass line belongs
  to the pipeline its thread opened last. A pipeline run as a pass of
  another (e.g. 'simplification: simplification', the fixed point of the
  simplification passes) counts the time of its own passes too.
  """
  pipeline = {}  # thread -> (module, pipeline)
  seconds = collections.Counter()
  for line in log.splitlines():
    opened = _PIPELINE.match(line)
    if opened:
      thread, name, pipe = opened.groups()
      pipeline[thread] = (name, pipe)
      continue
    timed = _PASS.match(line)
    if timed:
      thread, name, value, unit = timed.groups()
      owner, pipe = pipeline.get(thread, (None, None))
      if owner == module:
        seconds[f'{pipe}: {name}'] += float(value) * _XLA_UNITS[unit]
  return {name: round(s, 6) for name, s in seconds.most_common(n)}


def _disable_persistent_cache():
  import jax  # pylint: disable=g-import-not-at-top

  jax.config.update('jax_enable_compilation_cache', False)


# -- program size ------------------------------------------------------------


def _scope_names(name_stack):
  """'vmap(step)/forward/fwd_position' -> ['step', 'forward', ...]."""
  names = []
  for part in str(name_stack).split('/'):
    while True:  # unwrap transformations: vmap(jvp(step)) -> step
      m = re.fullmatch(r'([\w.\-]+)\((.*)\)', part)
      if not m or m.group(1) in ('jit', 'pjit'):
        break  # 'jit(step)' is a jitted function, not MJX's scope
      part = m.group(2)
    if part:
      names.append(part)
  return names


def _flat_eqns(jaxpr, prefix=()):
  """(scope path, primitive) of every equation, nested jaxprs inlined."""
  from jax._src import core  # pylint: disable=g-import-not-at-top

  for eqn in jaxpr.eqns:
    path = prefix + tuple(_scope_names(eqn.source_info.name_stack))
    yield path, eqn.primitive.name
    for sub in core.jaxprs_in_params(eqn.params):
      yield from _flat_eqns(sub, path)


def _scope_copies(eqns, scope, first_child):
  """Copies of `scope`: runs of consecutive equations inside it.

  A run also ends where `first_child` (the scope each copy opens first)
  starts again, so that two copies back to back count twice.
  """
  copies, inside, previous = 0, False, None
  for path, _ in eqns:
    if scope not in path:
      inside = False
      continue
    i = path.index(scope)
    child = path[i + 1] if len(path) > i + 1 else None
    if not inside or (
        first_child is not None
        and child == first_child
        and previous != first_child
    ):
      copies += 1
    inside, previous = True, child
  return copies


# Control-flow and transformation names in a name stack that are not scopes
# of the program's pieces.
_STRUCTURAL_SCOPES = frozenset(
    ('while', 'body', 'cond', 'scan', 'checkpoint', 'remat', 'eval_jaxpr')
)


def scope_counts(eqns, depth=4):
  """Equations per named scope path (its first `depth` named scopes).

  Args:
    eqns: `(scope path, primitive)` pairs, as `_flat_eqns` yields them.
    depth: how many nested scope names a path keeps ('forward/solve').

  Returns:
    `{path: equations}`, largest first; '' counts the equations outside
    every named scope. The counts sum to the number of equations.
  """
  counts = collections.Counter()
  for path, _ in eqns:
    names = [
        n
        for n in path
        if n not in _STRUCTURAL_SCOPES and not n.startswith('branch_')
    ]
    counts['/'.join(names[:depth])] += 1
  return dict(counts.most_common())


_SCOPE_ROWS = 30  # scopes kept per program in the JSON


def _stablehlo_ops(module):
  """Operations in an MLIR module, outlined functions counted once."""
  count = 0

  def walk(op):
    nonlocal count
    for region in op.regions:
      for block in region.blocks:
        for inner in block.operations:
          count += 1
          walk(inner.operation)

  walk(module.operation)
  return count


def _hlo_counts(text):
  instructions = len(
      re.findall(r'(?m)^\s*(?:ROOT\s+)?%?[\w.\-]+\s*=\s*\S', text)
  )
  whiles = len(re.findall(r'\bwhile\(', text))
  return instructions, whiles


def program_sizes(traced_jaxpr, lowered, compiled):
  sizes = {}
  if traced_jaxpr is not None:
    eqns = list(_flat_eqns(traced_jaxpr.jaxpr))
    sizes['jaxpr_eqns'] = len(eqns)
    # The largest scopes, to see where a program's equations come from.
    sizes['jaxpr_scopes'] = dict(list(scope_counts(eqns).items())[:_SCOPE_ROWS])
    for scope, first_child in _SCOPES.items():
      sizes[f'mjx_{scope}'] = _scope_copies(eqns, scope, first_child)
  try:
    sizes['stablehlo_ops'] = _stablehlo_ops(lowered.compiler_ir('stablehlo'))
  except Exception:  # pylint: disable=broad-except
    text = lowered.as_text()
    sizes['stablehlo_ops'] = len(
        re.findall(r'(?m)^\s*(?:%\S+ = )?"?\w+\.', text)
    )
  sizes['hlo_instructions'], sizes['hlo_while_loops'] = _hlo_counts(
      compiled.as_text() or ''
  )
  return sizes


# -- timing one program ------------------------------------------------------


def measure(fn, args):
  """Times trace, lowering and compilation of `jax.jit(fn)` on `args`."""
  import jax  # pylint: disable=g-import-not-at-top

  jitted = jax.jit(fn)
  row = {}
  if hasattr(jitted, 'trace'):
    t0 = time.perf_counter()
    traced = jitted.trace(*args)
    row['trace_s'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    lowered = traced.lower()
    row['lower_s'] = time.perf_counter() - t0
    jaxpr = traced.jaxpr
  else:  # older JAX: lowering includes tracing
    t0 = time.perf_counter()
    lowered = jitted.lower(*args)
    row['trace_s'] = None
    row['lower_s'] = time.perf_counter() - t0
    jaxpr = jax.make_jaxpr(fn)(*args)
  t0 = time.perf_counter()
  compiled = lowered.compile()
  row['compile_s'] = time.perf_counter() - t0
  row['total_s'] = (row['trace_s'] or 0.0) + row['lower_s'] + row['compile_s']
  row.update(program_sizes(jaxpr, lowered, compiled))
  # The module's name ('jit_rollout'), as XLA's timers name it.
  row['module'] = (
      lowered.compiler_ir('stablehlo').operation.attributes['sym_name'].value
  )
  return row


# -- the programs ------------------------------------------------------------


def _programs(env, worlds, steps):
  """{name: (fn, args)} of the four non-PPO programs."""
  import jax  # pylint: disable=g-import-not-at-top

  import common  # pylint: disable=g-import-not-at-top

  model, n = env.mjx_model, env.n_sub_steps
  keys = jax.random.split(jax.random.key(0), worlds)
  actions = common.random_actions(env, worlds)
  reset = jax.vmap(env.reset)
  raw_reset = common.raw_reset(model, jit=False)
  return {
      'raw_reset': lambda: (raw_reset, (keys,)),
      'reset': lambda: (reset, (keys,)),
      'raw_step': lambda: (
          common.raw_rollout(model, n, steps, jit=False),
          (jax.eval_shape(raw_reset, keys), actions),
      ),
      'step': lambda: (
          common.env_rollout(env, steps, jit=False),
          (jax.eval_shape(reset, keys), actions),
      ),
  }


def _raw_brax_env(env):
  """A minimal Brax environment: raw MJX reset and step on `env`'s model."""
  # pylint: disable=g-import-not-at-top
  from brax.envs import base as brax_base
  import jax
  import jax.numpy as jnp
  from mujoco import mjx

  import common
  # pylint: enable=g-import-not-at-top

  model, n = env.mjx_model, env.n_sub_steps
  reset_one = common.raw_reset(model, jit=False)  # vmapped: one key -> batch

  def obs(data):
    return jnp.concatenate([data.qpos, data.qvel])

  class RawMjxEnv(brax_base.Env):
    """Raw MJX under Brax's own wrappers; reward: -|qvel|^2."""

    def reset(self, rng):
      data = jax.tree.map(lambda x: x[0], reset_one(rng[None]))
      zero = jnp.zeros(())
      return brax_base.State(data, obs(data), zero, zero)

    def step(self, state, action):
      data = state.pipeline_state.replace(ctrl=action)
      data = jax.lax.fori_loop(0, n, lambda _, d: mjx.step(model, d), data)
      reward = -jnp.sum(data.qvel**2)
      return state.replace(pipeline_state=data, obs=obs(data), reward=reward)

    @property
    def observation_size(self):
      return model.nq + model.nv

    @property
    def action_size(self):
      return model.nu

    @property
    def backend(self):
      return 'mjx'

  return RawMjxEnv()


def measure_ppo(env, worlds, raw):
  """Wall time and JAX's compile events of a one-epoch `ppo.train`."""
  # pylint: disable=g-import-not-at-top
  import functools

  from brax.training.agents.ppo import networks as ppo_networks
  from brax.training.agents.ppo import train as ppo
  import jax

  from mjx_composer.adapters import brax as brax_adapter
  # pylint: enable=g-import-not-at-top

  events = collections.defaultdict(lambda: collections.defaultdict(float))

  def listener(event, duration, **kwargs):
    stage = {
        '/jax/core/compile/jaxpr_trace_duration': 'trace_s',
        '/jax/core/compile/jaxpr_to_mlir_module_duration': 'lower_s',
        '/jax/core/compile/backend_compile_duration': 'compile_s',
    }.get(event)
    if stage:
      events[kwargs.get('fun_name', '?')][stage] += duration

  jax.monitoring.register_event_duration_secs_listener(listener)
  # Brax 0.14 on JAX >= 0.10 needs the adapter's shim, also without BraxEnv.
  if hasattr(brax_adapter, 'install_jax_compat'):
    brax_adapter.install_jax_compat()
  brax_env = _raw_brax_env(env) if raw else brax_adapter.BraxEnv(env)
  episode_length = round(env.time_limit / env.control_timestep())
  unroll_length = 5
  if raw:
    kwargs = {'episode_length': episode_length}
    network_kwargs = {}
  else:
    kwargs = brax_adapter.training_kwargs(brax_env)
    network_kwargs = {'policy_obs_key': 'policy', 'value_obs_key': 'policy'}
  t0 = time.perf_counter()
  ppo.train(
      environment=brax_env,
      num_timesteps=worlds * unroll_length,  # one training step
      num_envs=worlds,
      batch_size=worlds,
      num_minibatches=1,
      unroll_length=unroll_length,
      num_updates_per_batch=1,
      num_evals=1,
      run_evals=False,
      seed=0,
      network_factory=functools.partial(
          ppo_networks.make_ppo_networks,
          policy_hidden_layer_sizes=(64, 64),
          value_hidden_layer_sizes=(256, 256),
          **network_kwargs,
      ),
      **kwargs,
  )
  wall = time.perf_counter() - t0
  row = {'wall_s': wall}
  for stage in ('trace_s', 'lower_s', 'compile_s'):
    row[stage] = sum(e[stage] for e in events.values())
  row['total_s'] = row['trace_s'] + row['lower_s'] + row['compile_s']
  name, largest = max(events.items(), key=lambda kv: kv[1].get('compile_s', 0))
  row['largest_program'] = {'name': name, **largest}
  row['programs'] = {
      name: dict(e)
      for name, e in sorted(
          events.items(), key=lambda kv: -kv[1].get('compile_s', 0.0)
      )
  }
  return row


# -- one measurement (a worker process) --------------------------------------


# `<task>:fixed`: the task with its per-episode randomization off
# (`randomize=False`), to see what randomization adds to each program.
FIXED = 'fixed'
_RANDOMIZABLE = ('reach', 'push')


def task_name(name):
  """`--tasks`' type: a bundled task, or `walk:<variant>` (module docstring)."""
  import common  # pylint: disable=g-import-not-at-top
  import playground_compare  # pylint: disable=g-import-not-at-top

  base, _, variant = name.partition(':')
  if name in common.TASKS:
    return name
  if variant == FIXED and base in _RANDOMIZABLE:
    return name
  if base == 'walk' and variant and variant not in ('playground', 'raw'):
    try:
      return 'walk:' + playground_compare.program_name(variant)
    except argparse.ArgumentTypeError as e:
      raise argparse.ArgumentTypeError(f'{name!r}: {e}') from None
  raise argparse.ArgumentTypeError(
      f'unknown task {name!r}: one of {", ".join(common.TASKS)}, '
      'walk:<variant> (ours_on, ours_off, only_<feature>[+<feature>...]), '
      f'or {"/".join(_RANDOMIZABLE)}:{FIXED}'
  )


def measured_programs(tasks, programs):
  """The (task, program) pairs to measure, in order.

  A walk variant's raw programs are its base task's (the same model): they
  are measured once, under the base task, when it is among `tasks`.
  """
  pairs = []
  for task in tasks:
    base, _, variant = task.partition(':')
    for program in programs:
      if not (program.startswith('raw_') and variant and base in tasks):
        pairs.append((task, program))
  return pairs


def make_task_env(task, **options):
  """The `Environment` of a `--tasks` entry, as the benchmarks build it.

  `options`: the `ExecutionOptions` fields the command line sets
  (`share_reset_forward`, `reset_forward`, `branches`), for the
  `Environment` (None: its default).
  """
  import common  # pylint: disable=g-import-not-at-top
  import playground_compare  # pylint: disable=g-import-not-at-top

  options = {k: v for k, v in options.items() if v is not None}
  base, _, variant = task.partition(':')
  if not variant or variant == FIXED:
    return common.make_env(
        base,
        **options,
        **({'randomize': False} if variant == FIXED else {}),
    )
  return playground_compare.env_variants([variant], **options)[variant]


def run_one(task, program, worlds, steps, options=None):
  """Builds `task`'s environment and measures `program`; returns a dict."""
  _disable_persistent_cache()
  # pylint: disable=g-import-not-at-top
  import jax
  from jax._src import compilation_cache

  import common
  # pylint: enable=g-import-not-at-top

  from mjx_composer import platform  # pylint: disable=g-import-not-at-top
  from mjx_composer.platform import prng_lowering  # pylint: disable=g-import-not-at-top

  # As our scripts compile (MJX_COMPOSER_THREEFRY_KERNEL=0: without).
  platform.configure(compilation_cache=False)
  threefry_kernel = prng_lowering.is_enabled()
  device = jax.devices()[0]
  if worlds is None:
    worlds = 8 if device.platform == 'cpu' else 1024
  # One-time backend and compiler start-up, kept out of the measurement.
  jax.jit(lambda x: x + 1).lower(1.0).compile()
  t0 = time.perf_counter()
  env = make_task_env(task, **(options or {}))
  build_s = time.perf_counter() - t0
  assert not compilation_cache.is_persistent_cache_enabled()
  if program in _PPO_PROGRAMS:
    row = measure_ppo(env, worlds, raw=program == 'raw_ppo')
  else:
    fn, args = _programs(env, worlds, steps)[program]()
    row = measure(fn, args)
  row.update(
      task=task,
      program=program,
      worlds=worlds,
      steps=steps,
      n_sub_steps=env.n_sub_steps,
      build_s=build_s,
      device=device.device_kind,
      platform=device.platform,
      jax=jax.__version__,
      threefry_gpu_kernel=threefry_kernel,
      share_reset_forward=env.share_reset_forward,
      branches=env.branches,
      reset_forward_stage=env.reset_forward_stage,
      stored_restart=env.stored_restart,
  )
  return row


def run_worker(script, args, phases=False):
  """`python script --worker ROW_JSON *args` in a fresh process: its row.

  The worker measures and writes its row (a dict) to ROW_JSON; returns
  None when the process fails (its output says why). With `phases`, the
  worker prints XLA's compile timers, and the row gets the measured
  program's (`xla_phases`); the worker's other output passes through.
  """
  with tempfile.TemporaryDirectory() as tmp:
    path = os.path.join(tmp, 'row.json')
    cmd = [sys.executable, os.path.abspath(script), '--worker', path, *args]
    done = subprocess.run(
        cmd,
        check=False,
        stderr=subprocess.PIPE if phases else None,
        text=True,
        env=dict(os.environ, **XLA_TIMER_ENV) if phases else None,
    )
    if phases:  # XLA's INFO lines ('I1130 02:38:04.2 ...') stay out
      sys.stderr.write(
          ''.join(
              line
              for line in done.stderr.splitlines(keepends=True)
              if not re.match(r'I\d{4} ', line)
          )
      )
    if done.returncode:
      return None
    with open(path) as f:
      row = json.load(f)
    if phases:
      row.update(xla_phases(done.stderr, row.get('module')))
      row['xla_passes'] = xla_passes(done.stderr, row.get('module'))
    return row


def _run_isolated(task, program, worlds, steps, options=None, phases=False):
  """`run_one` in a fresh Python process (`run_worker`)."""
  args = ['--tasks', task, '--programs', program, '--steps', str(steps)]
  if worlds is not None:
    args += ['--worlds', str(worlds)]
  options = options or {}
  share = options.get('share_reset_forward')
  if share is not None:
    args += ['--share-reset-forward', 'on' if share else 'off']
  for name in ('reset_forward', 'branches'):
    if options.get(name) is not None:
      args += ['--' + name.replace('_', '-'), options[name]]
  return run_worker(__file__, args, phases)


# -- report ------------------------------------------------------------------


def _ratio(a, b):
  if a is None or b is None or not b:
    return None
  return a / b


def ratios(rows):
  """composed / raw per task and program pair."""
  by_key = {(r['task'], r['program']): r for r in rows}
  out = []
  pairs = (('reset', 'raw_reset'), ('step', 'raw_step'), ('ppo', 'raw_ppo'))
  for task in dict.fromkeys(r['task'] for r in rows):
    for composed, raw in pairs:
      c = by_key.get((task, composed))
      # A walk variant has its base task's model: its raw programs.
      r = by_key.get((task, raw)) or by_key.get((task.partition(':')[0], raw))
      if not c or not r:
        continue
      row = {'task': task, 'program': composed}
      for key in _TIME_KEYS + _XLA_PHASE_KEYS + _SIZE_KEYS + ('wall_s',):
        row[key] = _ratio(c.get(key), r.get(key))
      out.append(row)
  return out


def _fmt(x, spec):
  return '-' if x is None else format(x, spec)


def print_scopes(rows, n):
  """Each program's `n` largest named scopes, in jaxpr equations."""
  for r in rows:
    scopes = list(r.get('jaxpr_scopes', {}).items())[:n]
    print(f'\n{r["task"]} / {r["program"]}: jaxpr equations by scope')
    for path, count in scopes:
      print(f'  {count:>7,}  {path or "(no scope)"}')


def print_passes(rows, n):
  """Each program's `n` slowest HLO passes (`xla_passes`)."""
  for r in rows:
    passes = list(r.get('xla_passes', {}).items())[:n]
    if passes:
      print(f'\n{r["task"]} / {r["program"]}: XLA\'s slowest HLO passes')
      for name, seconds in passes:
        print(f'  {seconds:8.2f} s  {name}')


def print_tables(rows, ratio_rows):
  print(
      '\n| task | program | trace s | lower s | compile s | total s | jaxpr '
      'eqns | StableHLO ops | HLO instrs | HLO whiles | mjx.step | forward '
      '| solver |'
  )
  print('|---|---|---|---|---|---|---|---|---|---|---|---|---|')
  for r in rows:
    print(
        f'| {r["task"]} | {r["program"]} | {_fmt(r.get("trace_s"), ".2f")} | '
        f'{_fmt(r.get("lower_s"), ".2f")} | '
        f'{_fmt(r.get("compile_s"), ".2f")} | '
        f'{_fmt(r.get("total_s"), ".2f")} | '
        f'{_fmt(r.get("jaxpr_eqns"), ",")} | '
        f'{_fmt(r.get("stablehlo_ops"), ",")} | '
        f'{_fmt(r.get("hlo_instructions"), ",")} | '
        f'{_fmt(r.get("hlo_while_loops"), "d")} | '
        f'{_fmt(r.get("mjx_step"), "d")} | '
        f'{_fmt(r.get("mjx_forward"), "d")} | '
        f'{_fmt(r.get("mjx_solve"), "d")} |'
    )
  print(
      '\n| task | composed / raw | trace | compile | total | jaxpr eqns | '
      'StableHLO ops | HLO instrs |'
  )
  print('|---|---|---|---|---|---|---|---|')
  for r in ratio_rows:
    print(
        f'| {r["task"]} | {r["program"]} | {_fmt(r["trace_s"], ".2f")} | '
        f'{_fmt(r["compile_s"], ".2f")} | {_fmt(r["total_s"], ".2f")} | '
        f'{_fmt(r["jaxpr_eqns"], ".2f")} | {_fmt(r["stablehlo_ops"], ".2f")} '
        f'| {_fmt(r["hlo_instructions"], ".2f")} |'
    )


def _write(args, rows, failed, unfinished):
  """Writes the JSON record of the programs measured so far."""
  import common  # pylint: disable=g-import-not-at-top

  common.write_json(
      args.out,
      {
          'device': rows[0]['device'] if rows else None,
          'platform': rows[0]['platform'] if rows else None,
          'jax': rows[0]['jax'] if rows else None,
          'worlds': rows[0]['worlds'] if rows else args.worlds,
          'steps': args.steps,
          'isolated': not args.in_process,
          'persistent_cache': False,
          'failed': failed,
          'unfinished': unfinished,
          'results': rows,
          'ratios': ratios(rows),
      },
  )


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument(
      '--tasks',
      nargs='+',
      type=task_name,
      default=['reach', 'push'],
      help='bundled tasks (reach, push, walk, joystick) or walk:<variant>',
  )
  parser.add_argument(
      '--worlds',
      type=int,
      default=None,
      help='batch size of every program (default: 8 on the CPU, 1024 else)',
  )
  parser.add_argument(
      '--steps',
      type=int,
      default=2,
      help='control steps scanned in the step programs',
  )
  parser.add_argument(
      '--ppo',
      action='store_true',
      help="also time Brax PPO's compilation (slow)",
  )
  parser.add_argument(
      '--programs',
      nargs='+',
      default=None,
      choices=_PROGRAMS + _PPO_PROGRAMS,
      help='measure only these programs',
  )
  parser.add_argument(
      '--in-process',
      action='store_true',
      help='measure in this process, not one fresh process per program',
  )
  parser.add_argument(
      '--out',
      default=os.path.join(os.environ.get('OUT', '.'), 'compile_time.json'),
  )
  import common  # pylint: disable=g-import-not-at-top

  common.add_share_reset_forward_arg(parser)
  parser.add_argument(
      '--reset-forward',
      choices=('observed', 'full'),
      default=None,
      help="ExecutionOptions(reset_forward=...) (default: the Environment's, "
      "'observed')",
  )
  parser.add_argument(
      '--branches',
      choices=('loop', 'cond'),
      default=None,
      help="ExecutionOptions(branches=...) (default: the Environment's, "
      "'cond' on a CPU, 'loop' elsewhere)",
  )
  parser.add_argument(
      '--scopes',
      type=int,
      default=0,
      metavar='N',
      help="print each program's N largest named scopes (jaxpr equations)",
  )
  parser.add_argument(
      '--xla-phases',
      action='store_true',
      help="also record XLA's time in its HLO passes and its backend, and "
      'its slowest HLO passes, from its own timers (each program in its own '
      'process)',
  )
  parser.add_argument('--worker', metavar='ROW_JSON', help=argparse.SUPPRESS)
  args = parser.parse_args(argv)
  env_options = {
      'share_reset_forward': common.share_reset_forward(args),
      'reset_forward': args.reset_forward,
      'branches': args.branches,
  }
  programs = args.programs or (
      list(_PROGRAMS) + (list(_PPO_PROGRAMS) if args.ppo else [])
  )

  if args.worker:  # a worker process: one task, one program
    row = run_one(
        args.tasks[0], programs[0], args.worlds, args.steps, env_options
    )
    with open(args.worker, 'w') as f:
      json.dump(row, f)
    return 0

  if args.in_process:
    if args.xla_phases:
      parser.error(
          '--xla-phases needs a process per program (not --in-process)'
      )
    _disable_persistent_cache()
  rows, failed = [], []
  pairs = measured_programs(args.tasks, programs)
  for task, program in pairs:
    print(f'{task}: {program} ...', flush=True)
    if args.in_process:
      row = run_one(task, program, args.worlds, args.steps, env_options)
    else:
      row = _run_isolated(
          task,
          program,
          args.worlds,
          args.steps,
          env_options,
          phases=args.xla_phases,
      )
    if row is None:
      print(f'{task}: {program} FAILED (see above)', flush=True)
      failed.append(f'{task}/{program}')
    else:
      rows.append(row)
      print(
          f'{task}: {program:<9} trace {_fmt(row.get("trace_s"), ".2f")} s, '
          f'lower {row["lower_s"]:.2f} s, compile {row["compile_s"]:.2f} s'
          + (f', wall {row["wall_s"]:.1f} s' if 'wall_s' in row else '')
          + (
              f' (XLA: HLO passes {row["xla_hlo_passes_s"]:.2f} s, backend '
              f'{row["xla_backend_s"]:.2f} s)'
              if 'xla_backend_s' in row and 'xla_hlo_passes_s' in row
              else ''
          ),
          flush=True,
      )
    # After every program: a run stopped by a time limit keeps what it
    # measured (`unfinished` names what it had left).
    left = [f'{t}/{p}' for t, p in pairs[len(rows) + len(failed) :]]
    _write(args, rows, failed, left)

  if not rows:
    print('Nothing measured.')
    return 1
  ratio_rows = ratios(rows)
  print(
      f'\n{rows[0]["platform"]}: {rows[0]["device"]}, JAX {rows[0]["jax"]}, '
      f'{rows[0]["worlds"]} worlds, {args.steps} scanned steps; JSON: '
      f'{args.out}'
  )
  print_tables(rows, ratio_rows)
  if args.scopes:
    print_scopes(rows, args.scopes)
  if args.xla_phases:
    print_passes(rows, 10)
  if failed:
    print(f'\nFAILED: {", ".join(failed)}')
  return 1 if failed else 0


if __name__ == '__main__':
  sys.exit(main())
