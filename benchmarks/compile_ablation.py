"""What each part of per-episode randomization adds to the step's compile time.

The composed step program holds a reset (same-step auto-reset), and with it
the task's per-episode randomization. This script compiles the step program
of `--task` with parts of that randomization taken out (monkeypatched, each
variant in a fresh process, the persistent cache off, as
`compile_time.py` measures), so each part's share of the compile time shows:

* baseline:          the step program as shipped;
* no_draws:          `Uniform` draws return their midpoint (no threefry
                     hash per draw; key splits stay);
* no_set_const:      the `mj_setConst` re-derivation skipped (invweights,
                     `actuator_acc0`, ... keep the host model's values);
* no_inertia:        body mass, inertia and inertial frames not re-derived
                     from the varied geoms;
* no_hook_kinematics: no kinematics before the `initialize_episode` hooks;
* no_all:            the four above together;
* raw_step:          raw MJX's step program (`compile_time.py`'s);
* raw_step_batched_model: the same with every model field that the composed
                     state carries per world (`State.model_fields`) batched
                     per world, as a domain-randomization wrapper (Brax's,
                     Playground's) compiles it.

The variants change the program's results: they measure, they do not run.

    python benchmarks/compile_ablation.py --task reach --repeats 2
"""

import argparse
import json
import os
import sys

import compile_time

VARIANTS = (
    'baseline',
    'no_draws',
    'no_set_const',
    'no_inertia',
    'no_hook_kinematics',
    'no_all',
    'raw_step',
    'raw_step_batched_model',
)
PARTS = ('no_draws', 'no_set_const', 'no_inertia', 'no_hook_kinematics')


def remove(part, setattr_=setattr):
  """Monkeypatches one part of the randomization out of the package.

  Args:
    part: one of `PARTS`.
    setattr_: how to patch (tests pass pytest's `monkeypatch.setattr`).
  """
  # pylint: disable=g-import-not-at-top
  import jax.numpy as jnp

  from mjx_composer import kinematics
  from mjx_composer.compiler import inertia
  from mjx_composer.compiler import set_const
  from mjx_composer.variation import base
  from mjx_composer.variation import distributions
  # pylint: enable=g-import-not-at-top

  if part == 'no_draws':

    def midpoint(self, key, shape, low, high):
      del self, key
      return low + (high - low) * jnp.full(shape, 0.5, base.float_dtype(low))

    setattr_(distributions.Uniform, '_draw', midpoint)
  elif part == 'no_set_const':
    setattr_(set_const, 'update', lambda *args, **kwargs: None)
  elif part == 'no_inertia':
    setattr_(inertia, 'bodies_inertial', lambda *args, **kwargs: ())
  elif part == 'no_hook_kinematics':
    apply = kinematics.ReferenceKinematics.apply

    def hooks_skip(self, model, data, written=()):
      # The hooks' call passes no `written`; `set_const`'s passes its fields.
      return apply(self, model, data, written) if written else data

    setattr_(kinematics.ReferenceKinematics, 'apply', hooks_skip)
  else:
    raise ValueError(part)


def batched_model_step(env, worlds, steps):
  """(fn, args): raw MJX's step with the carried model fields per world."""
  # pylint: disable=g-import-not-at-top
  import jax
  from mujoco import mjx

  import common
  # pylint: enable=g-import-not-at-top

  model, n = env.mjx_model, env.n_sub_steps
  keys = jax.random.split(jax.random.key(0), worlds)
  names = tuple(jax.eval_shape(env.reset, keys[0]).model_fields)
  raw_reset = common.raw_reset(model, jit=False)

  def per_world(value):
    return jax.ShapeDtypeStruct((worlds,) + value.shape, value.dtype)

  fields = {
      name: jax.tree.map(per_world, getattr(model, name)) for name in names
  }

  def rollout(fields, data, ctrl):
    step = jax.vmap(lambda f, d: mjx.step(model.replace(**f), d))

    def control_step(d, _):
      d = d.replace(ctrl=ctrl)
      d = jax.lax.fori_loop(0, n, lambda _, x: step(fields, x), d)
      return d, None

    return jax.lax.scan(control_step, data, None, length=steps)[0], ctrl

  args = (
      fields,
      jax.eval_shape(raw_reset, keys),
      common.random_actions(env, worlds),
  )
  return rollout, args


def run_variant(task, variant, worlds, steps):
  """Measures one variant in this process; returns compile_time's row."""
  compile_time._disable_persistent_cache()  # pylint: disable=protected-access
  import jax  # pylint: disable=g-import-not-at-top

  from mjx_composer import cpu_linalg  # pylint: disable=g-import-not-at-top
  from mjx_composer import prng_lowering  # pylint: disable=g-import-not-at-top

  prng_lowering.enable()
  cpu_linalg.enable()
  for part in PARTS if variant == 'no_all' else (variant,):
    if part in PARTS:
      remove(part)
  jax.jit(lambda x: x + 1).lower(1.0).compile()  # backend start-up
  env = compile_time.make_task_env(task)
  if variant == 'raw_step_batched_model':
    fn, args = batched_model_step(env, worlds, steps)
  else:
    program = 'raw_step' if variant == 'raw_step' else 'step'
    # pylint: disable-next=protected-access
    fn, args = compile_time._programs(env, worlds, steps)[program]()
  row = compile_time.measure(fn, args)
  row.update(task=task, variant=variant, worlds=worlds, steps=steps)
  row['device'] = jax.devices()[0].device_kind
  return row


def _run_isolated(task, variant, worlds, steps):
  return compile_time.run_worker(
      __file__,
      [
          '--task',
          task,
          '--variants',
          variant,
          '--worlds',
          str(worlds),
          '--steps',
          str(steps),
      ],
  )


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--task', default='reach', type=compile_time.task_name)
  parser.add_argument(
      '--variants', nargs='+', choices=VARIANTS, default=VARIANTS
  )
  parser.add_argument('--worlds', type=int, default=8)
  parser.add_argument('--steps', type=int, default=2)
  parser.add_argument('--repeats', type=int, default=1)
  parser.add_argument(
      '--out',
      default=os.path.join(os.environ.get('OUT', '.'), 'compile_ablation.json'),
  )
  parser.add_argument('--worker', metavar='ROW_JSON', help=argparse.SUPPRESS)
  args = parser.parse_args(argv)
  if args.worker:
    row = run_variant(args.task, args.variants[0], args.worlds, args.steps)
    with open(args.worker, 'w') as f:
      json.dump(row, f)
    return 0

  rows = []
  for repeat in range(args.repeats):
    for variant in args.variants:
      row = _run_isolated(args.task, variant, args.worlds, args.steps)
      if row is None:
        print(f'{variant}: FAILED (see above)', flush=True)
        continue
      row['repeat'] = repeat
      rows.append(row)
      print(
          f'{variant:<24} total {row["total_s"]:6.2f} s (trace'
          f' {row["trace_s"]:.2f}, lower {row["lower_s"]:.2f}, compile'
          f' {row["compile_s"]:.2f}), {row["hlo_instructions"]:,} HLO'
          ' instructions',
          flush=True,
      )
  with open(args.out, 'w') as f:
    json.dump({'task': args.task, 'rows': rows}, f, indent=1)

  def mean_total(variant):
    totals = [r['total_s'] for r in rows if r['variant'] == variant]
    return sum(totals) / len(totals) if totals else None

  raw = mean_total('raw_step')
  print(
      f'\n{args.task}, {args.worlds} worlds, {rows[0]["device"]}: mean of'
      f' {args.repeats}; JSON: {args.out}'
  )
  print('| variant | total s | / raw MJX step | HLO instructions |')
  print('|---|---|---|---|')
  for variant in args.variants:
    total = mean_total(variant)
    if total is None:
      continue
    hlo = next(r['hlo_instructions'] for r in rows if r['variant'] == variant)
    ratio = f'{total / raw:.2f}' if raw else '-'
    print(f'| {variant} | {total:.2f} | {ratio} | {hlo:,} |')
  return 0


if __name__ == '__main__':
  sys.exit(main())
