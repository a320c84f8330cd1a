"""What a bundled task's sensors are of one `mjx.step`: program size and time.

`Environment(substep_sensors='read')` computes the sensors once per control
step instead of at every physics step (`mjx_composer.substep_sensors`). This
measures what that skips, on the task's compiled model: one batched
`mjx.step` with the model's sensors and with `mjDSBL_SENSOR`, as

* jaxpr equations (those of every sub-jaxpr included), HLO instructions of
  the compiled program;
* seconds per call (median of `--repeats`, `--worlds` worlds from the
  model's `qpos0`) on the default device.

    python benchmarks/sensor_share.py --task walk --worlds 8192
    python benchmarks/sensor_share.py --task reach --worlds 64   # CPU
"""

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer import substep_sensors

import common  # benchmarks/common.py
import compile_time  # benchmarks/compile_time.py


def measure(model, worlds, repeats):
  """Sizes and seconds of one `vmap(mjx.step)` of `model` on `worlds`."""
  data = common.raw_data(model, worlds)
  data = data.replace(ctrl=0.1 * jnp.ones_like(data.ctrl))
  step = jax.vmap(lambda d: mjx.step(model, d))
  lowered = jax.jit(step).lower(data)
  compiled = lowered.compile()
  sizes = compile_time.program_sizes(
      jax.make_jaxpr(step)(data), lowered, compiled
  )
  return {
      'jaxpr_eqns': sizes['jaxpr_eqns'],
      'hlo_instructions': sizes['hlo_instructions'],
      'seconds_per_call': common.time_fn(
          lambda d: (compiled(d),), (data,), repeats
      ),
  }


def main():
  parser = common.make_parser(
      __doc__, worlds=[64], repeats=5, out='sensor_share.json'
  )
  parser.add_argument('--task', default='walk', choices=common.TASKS)
  args = parser.parse_args()
  device = common.print_device()
  env = common.make_env(args.task)
  model = env.mjx_model
  results = []
  for worlds in args.worlds:
    row = {'worlds': worlds, 'sensors': env.mj_model.nsensor}
    for name, variant in (
        ('with_sensors', model),
        ('without_sensors', substep_sensors.without_sensors(model)),
    ):
      row[name] = measure(variant, worlds, args.repeats)
    row['share_of_jaxpr'] = 1 - (
        row['without_sensors']['jaxpr_eqns'] / row['with_sensors']['jaxpr_eqns']
    )
    row['share_of_time'] = 1 - (
        row['without_sensors']['seconds_per_call']
        / row['with_sensors']['seconds_per_call']
    )
    results.append(row)
    print(
        f'{args.task}, {worlds} worlds: sensors are '
        f'{row["share_of_jaxpr"]:.1%} of mjx.step\'s jaxpr equations '
        f'({row["with_sensors"]["jaxpr_eqns"]:,} with, '
        f'{row["without_sensors"]["jaxpr_eqns"]:,} without) and '
        f'{row["share_of_time"]:.1%} of its time',
        flush=True,
    )
    common.write_results(args.out, device, results, task=args.task)
  print(f'Wrote {args.out}')


if __name__ == '__main__':
  main()
