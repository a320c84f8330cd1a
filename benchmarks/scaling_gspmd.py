"""Scaling with XLA's partitioner (GSPMD): one device against two.

`scaling.py`'s default path (`sharding.per_device`, a `shard_map`) crashed
XLA's GPU compiler (segmentation fault in `backend_compile_and_load`) on the
2-GPU machine with JAX 0.11.2, in Shardy; `sharding` now compiles it with
GSPMD on several GPUs (`mjx_composer.partitioner`). This measures the plain
alternative that ran before that fix: the
batch placed with a `NamedSharding` over the world axis and the same
`jax.jit` programs as on one device (`common.raw_rollout`,
`common.env_rollout` of the bundled reach task with same-step auto-reset),
65,536 worlds, 10 control steps per call, median of 3 calls. Prints
physics steps/s and the scaling efficiency (2-device / (2 x 1-device)).

    python benchmarks/scaling_gspmd.py
"""

import jax
import jax.numpy as jnp
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

import common  # benchmarks/common.py

W, STEPS = 65536, 10
env = common.make_env('reach')
model = env.initial_physics().model
n = env.task.physics_steps_per_control_step
res = {}
for ndev in (1, 2):
  mesh = Mesh(jax.devices()[:ndev], ('w',))
  sh = NamedSharding(mesh, P('w'))
  data = jax.device_put(common.raw_data(model, W), sh)
  ctrl = jax.device_put(jnp.zeros((W, model.nu)), sh)
  f = common.raw_rollout(model, n, STEPS)
  t = common.time_fn(f, (data, ctrl), 3)
  res[('raw', ndev)] = W * STEPS * n / t
  print('raw', ndev, f'{res[("raw", ndev)]:,.0f}', flush=True)
  keys = jax.device_put(jax.random.split(jax.random.key(0), W), sh)
  states = jax.jit(jax.vmap(env.reset))(keys)
  g = common.env_rollout(env, STEPS)
  acts = jax.device_put(jnp.zeros((W,) + env.action_spec().shape), sh)
  t = common.time_fn(g, (states, acts), 3)
  res[('composed', ndev)] = W * STEPS * n / t
  print('composed', ndev, f'{res[("composed", ndev)]:,.0f}', flush=True)
for k in ('raw', 'composed'):
  print(k, 'efficiency', res[(k, 2)] / (2 * res[(k, 1)]))
