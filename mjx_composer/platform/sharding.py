"""A batch of worlds spread over devices: the world axis sharded over a mesh.

Every world of a composed `Environment` runs on its own (`jax.vmap` of the
single-world `reset` and `step`), so a batch splits over devices along its
leading world axis with no communication at all. This module names that
placement and builds the jitted programs that keep to it:

    from mjx_composer.platform import sharding

    mesh = sharding.world_mesh()                     # every device, 1-D
    reset = sharding.batched_reset(env, mesh)        # keys -> States
    step = sharding.batched_step(env, mesh)          # (States, actions) -> ...
    states = reset(sharding.world_keys(jax.random.key(0), 65536, mesh))
    states = step(states, actions)                   # stays sharded

Device d of a mesh of D devices holds worlds `[d * n / D, (d + 1) * n / D)`
of a batch of n worlds (n must be a multiple of D), for every array of the
`State`; outputs come back sharded the same way.

**Each device runs its own worlds' program** (`per_device`: `jax.jit` of a
`jax.shard_map` over the world axis). A plain `jax.jit` with
`NamedSharding` inputs computes the same values, but XLA then partitions the
one batched program, and every data-dependent loop or branch of the batch
becomes a global decision: MJX's constraint solver iterates while any world
of the batch has not converged, and auto-reset computes the resets when any
world is done. Partitioned, each such predicate is an all-reduce across the
devices, at every solver iteration, and every device iterates until the
slowest world on any device has converged; and a restart that gathers the
ended worlds (`ExecutionOptions.auto_reset_batch`, by default on batches of
1,024 worlds or more) gathers them from every device. Under `shard_map` each
device decides for its own worlds, and the compiled programs hold no
collective.
A world's values do not depend on these decisions (converged worlds and
worlds that are not done pass through unchanged), so the trajectories are
the same either way; `tests/platform/test_sharding.py` checks them across 1, 2 and 4
devices and checks the compiled programs for collectives. On several GPUs
these programs are compiled with XLA's GSPMD partitioner instead of Shardy,
which crashed compiling them (`mjx_composer.platform.partitioner`).

The price of `shard_map`: a function run with `per_device` must treat worlds
independently (row i of every output depends only on row i of the inputs),
as `jax.vmap` of a single-world function does. A function that reduces over
the batch (a mean return) would reduce over each device's worlds only: jit
such functions with `jax.jit` and `world_sharding` instead.

**Several hosts.** Start the same program on every host and call
`jax.distributed.initialize` before anything else touches JAX:

    jax.distributed.initialize(
        coordinator_address='host0:1234',  # process 0's host, any free port
        num_processes=N, process_id=i)     # this process's index, 0..N-1
    env = composer.Environment(task)       # every process builds the same
    mesh = sharding.world_mesh()           # all devices of all processes
    states = sharding.batched_reset(env, mesh)(
        sharding.world_keys(jax.random.key(0), num_worlds, mesh))

(on a cluster JAX knows, such as Slurm or Cloud TPU, `initialize()` finds
its arguments itself). After it, `jax.devices()` lists the devices of every
process, so `world_mesh()` spans all hosts and each process holds the worlds
of its own devices: process p of P holds worlds `[p * n / P, (p + 1) * n /
P)` when the processes have equally many devices. The jitted programs are
the same on every host and each process runs its own devices' part; since
the programs hold no collective, the hosts do not wait for each other while
stepping. Arrays that span hosts are built from values every process has
(`put_worlds`, `world_keys`) or from each process's own worlds
(`put_local_worlds`); read them back with `local_worlds` (this process's
rows, no communication) or `gather_worlds` (every row on every process, an
all-gather; on CPU through JAX's gloo collectives, which give up when a
process is more than 30 s late, e.g. still compiling).

Known limitation: MJX (3.17) puts a model and data on `jax.devices()[0]`
unless given a device, and with several processes that is process 0's
device, which the others cannot address: building an `Environment` fails
there ("Number of addressable output shards must match ...: 0 vs. 1") until
`Environment` passes `device=jax.local_devices()[0]` to `mjx.put_model` and
`mjx.make_data`. `tests/platform/test_sharding.py` patches MJX so for its
two-process test.

A world's trajectory does not depend on the number of devices or hosts that
share the batch: its key and its actions fix it. `tests/platform/test_sharding.py`
runs 1, 2 and 4 devices in one process and 2 processes of 2 devices: bit
for bit equal where each device holds as many worlds, and otherwise equal
to float32 rounding (each device compiles the program for its own number of
worlds, and XLA may order a floating-point reduction differently for
another batch size, as on one device).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence
import weakref

import jax
from jax.experimental import multihost_utils
import jax.numpy as jnp
import numpy as np

from mjx_composer.platform import partitioner

# The mesh axis the world axis is sharded over.
WORLD_AXIS = 'worlds'

Mesh = jax.sharding.Mesh
NamedSharding = jax.sharding.NamedSharding
P = jax.sharding.PartitionSpec


def world_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
  """A 1-D mesh with axis `'worlds'` over `devices`.

  Args:
    devices: the devices to spread the worlds over; default `jax.devices()`,
      which after `jax.distributed.initialize` lists the devices of every
      process (`jax.local_devices()` would give each process a mesh of its
      own, and the processes' programs would not form one batch). They are
      ordered by process, then by id, so that each process's worlds are one
      contiguous block of the batch.

  Returns:
    The `jax.sharding.Mesh`.

  Raises:
    ValueError: if `devices` is empty or lists a device twice.
  """
  devices = list(jax.devices() if devices is None else devices)
  if not devices:
    raise ValueError(
        'world_mesh: `devices` is empty; pass at least one device, e.g. '
        'jax.devices()[:1], or devices=None for every device.'
    )
  if len(set(devices)) != len(devices):
    raise ValueError(f'world_mesh: a device is listed twice in {devices}.')
  devices.sort(key=lambda d: (d.process_index, d.id))
  return Mesh(np.array(devices), (WORLD_AXIS,))


def world_sharding(mesh: Mesh | None = None) -> NamedSharding:
  """Arrays whose leading (world) axis is split over `mesh`'s devices.

  Args:
    mesh: a mesh from `world_mesh`; default `world_mesh()`.
  """
  return NamedSharding(_mesh(mesh), P(WORLD_AXIS))


def check_num_worlds(num_worlds: int, mesh: Mesh | None = None) -> int:
  """Returns `num_worlds` if it splits evenly over `mesh`'s devices.

  Raises:
    ValueError: if it does not, saying which batch sizes and meshes would.
  """
  mesh = _mesh(mesh)
  devices = mesh.shape[WORLD_AXIS]
  if num_worlds % devices:
    up = -(-num_worlds // devices) * devices
    fewer = max(k for k in range(1, devices + 1) if num_worlds % k == 0)
    raise ValueError(
        f'{num_worlds} worlds cannot be split evenly over the {devices} '
        f'devices of the mesh: use a multiple of {devices} worlds (e.g. '
        f'{up}), or a mesh of fewer devices, such as '
        f'world_mesh(jax.devices()[:{fewer}]).'
    )
  return num_worlds


def count_worlds(tree) -> int:
  """The size of the leading (world) axis shared by `tree`'s arrays.

  Raises:
    ValueError: if the tree has no array, an array has no leading axis, or
      the arrays disagree on its size.
  """
  sizes = {
      np.shape(x)[0] if np.ndim(x) else None for x in jax.tree.leaves(tree)
  }
  if not sizes:
    raise ValueError('This tree holds no array: no world axis to shard.')
  if None in sizes or len(sizes) > 1:
    raise ValueError(
        'Every array of a batch of worlds has a leading world axis of the '
        f'same size; these arrays have leading sizes {sorted(map(str, sizes))}'
        ' (None: a scalar).'
    )
  return sizes.pop()


# -- placing arrays ------------------------------------------------------------


def put_worlds(tree, mesh: Mesh | None = None):
  """Places a batch of worlds (every world on every process) on the mesh.

  Args:
    tree: a pytree of arrays (numpy or JAX, PRNG keys too) whose leading axis
      is the world axis, holding every world of the batch. With several
      processes, each must pass the same values; use `put_local_worlds` when
      each process has only its own worlds.
    mesh: a mesh from `world_mesh`; default `world_mesh()`.

  Returns:
    The same tree of `jax.Array`s, sharded by `world_sharding(mesh)`.

  Raises:
    ValueError: if the number of worlds does not split over the devices.
  """
  mesh = _mesh(mesh)
  check_num_worlds(count_worlds(tree), mesh)
  sharding = world_sharding(mesh)
  if jax.process_count() == 1:
    return jax.device_put(tree, sharding)

  def put(x):
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
      return jax.device_put(x, sharding)  # already global: reshard
    # Each process builds its own devices' shards from the global value.
    data = np.asarray(jax.device_get(x))
    return jax.make_array_from_callback(data.shape, sharding, data.__getitem__)

  return _map_key_data(put, tree)


def put_local_worlds(tree, mesh: Mesh | None = None):
  """Joins each process's own worlds into one batch sharded over the mesh.

  Args:
    tree: a pytree of arrays whose leading axis holds this process's worlds,
      those of its devices in the mesh, in order (`local_worlds` gives them
      back). With one process this is every world, and `put_local_worlds`
      is `put_worlds`.
    mesh: a mesh from `world_mesh`; default `world_mesh()`.

  Returns:
    The tree of global `jax.Array`s, sharded by `world_sharding(mesh)`.
  """
  mesh = _mesh(mesh)
  local = count_worlds(tree)
  local_devices = sum(
      d.process_index == jax.process_index() for d in mesh.devices.flat
  )
  if not local_devices:
    raise ValueError(
        f'Process {jax.process_index()} has no device in this mesh.'
    )
  if local % local_devices:
    raise ValueError(
        f"{local} local worlds cannot be split evenly over this process's "
        f'{local_devices} devices of the mesh: pass a multiple of '
        f'{local_devices} worlds per process.'
    )
  sharding = world_sharding(mesh)
  global_worlds = local // local_devices * mesh.shape[WORLD_AXIS]

  def put(x):
    return jax.make_array_from_process_local_data(
        sharding,
        np.asarray(jax.device_get(x)),
        (global_worlds,) + np.shape(x)[1:],
    )

  return _map_key_data(put, tree)


def world_keys(key, num_worlds: int, mesh: Mesh | None = None):
  """`jax.random.split(key, num_worlds)`, sharded over the mesh.

  World i gets the same key whatever the mesh, so its episodes do not depend
  on how many devices share the batch.
  """
  mesh = _mesh(mesh)
  check_num_worlds(num_worlds, mesh)
  return put_worlds(jax.random.split(key, num_worlds), mesh)


# -- reading arrays back -------------------------------------------------------


def local_worlds(tree):
  """This process's worlds of a sharded batch, as numpy arrays.

  No communication: the rows of the worlds this process's devices hold, in
  world order (every world with one process). An array that is not split
  over the world axis (JAX leaves empty arrays replicated) gives the same
  rows. PRNG keys come back as their key data.

  Raises:
    ValueError: if this process's devices do not hold its block of rows.
  """

  def local(x):
    if not isinstance(x, jax.Array) or x.is_fully_addressable:
      return np.asarray(jax.device_get(x))
    lo, hi = _local_rows(x)
    out = np.empty((hi - lo,) + x.shape[1:], x.dtype)
    filled = np.zeros(hi - lo, bool)
    for shard in x.addressable_shards:
      rows = range(x.shape[0])[shard.index[0]]
      start, stop = max(rows.start, lo), min(rows.stop, hi)
      if start < stop:
        data = np.asarray(shard.data)
        out[start - lo : stop - lo] = data[
            start - rows.start : stop - rows.start
        ]
        filled[start - lo : stop - lo] = True
    if not filled.all():
      raise ValueError(
          f'Process {jax.process_index()} does not hold worlds {lo}..{hi - 1}'
          f' of this array (sharding {x.sharding}): place it with put_worlds.'
      )
    return out

  return jax.tree.map(local, _key_data(tree))


def _local_rows(x):
  """The rows `[lo, hi)` of this process's devices along the world axis."""
  sharding = x.sharding
  mesh = sharding.mesh if isinstance(sharding, NamedSharding) else None
  devices = list((mesh if mesh is not None else world_mesh()).devices.flat)
  mine = [
      i for i, d in enumerate(devices) if d.process_index == jax.process_index()
  ]
  if not mine:
    raise ValueError(
        f"Process {jax.process_index()} has no device in this array's mesh."
    )
  per_device = x.shape[0] // len(devices)
  return mine[0] * per_device, (mine[-1] + 1) * per_device


def gather_worlds(tree):
  """Every world of a sharded batch, as numpy arrays, on every process.

  With several processes this is an all-gather across them (every process
  must call it); with one it is `jax.device_get`. PRNG keys come back as
  their key data.
  """
  tree = _key_data(tree)
  if all(
      not isinstance(x, jax.Array) or x.is_fully_addressable
      for x in jax.tree.leaves(tree)
  ):
    return jax.tree.map(np.asarray, jax.device_get(tree))
  return multihost_utils.process_allgather(tree, tiled=True)


# -- programs ------------------------------------------------------------------


def per_device(
    fn: Callable[..., Any],
    mesh: Mesh | None = None,
    *,
    donate_argnums: int | Sequence[int] = (),
) -> WorldProgram:
  """Jits a batched function so that each device runs it on its own worlds.

  `jax.jit(jax.shard_map(fn, ...))` with every argument and output split
  along its leading (world) axis: each device calls `fn` on its block of
  worlds, with no communication between devices (see the module docstring
  for why not a plain `jax.jit` with shardings).

  Args:
    fn: a function of batched arrays whose leading axis is the world axis,
      returning batched arrays, that treats worlds independently (e.g.
      `jax.vmap` of a single-world function, or a `lax.scan` over one). Every
      argument must be batched; close over anything else.
    mesh: a mesh from `world_mesh`; default `world_mesh()`.
    donate_argnums: passed to `jax.jit`.

  Returns:
    The jitted function, a `WorldProgram`. Pass it arrays placed by
    `put_worlds` (or outputs of such functions) or numpy arrays; `jax.jit`
    refuses arrays committed to other devices. A batch that does not split
    evenly over the devices raises a `ValueError` saying what would.
  """
  mesh = _mesh(mesh)
  spec = P(WORLD_AXIS)
  # check_vma=False: MJX's solver returns, from the two branches of a
  # lax.cond, values that shard_map's varying-axis check types differently
  # (an unbatched False against a per-world flag). The check only guards
  # collectives' typing, and these programs have none.
  mapped = jax.shard_map(
      fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False
  )
  return WorldProgram(jax.jit(mapped, donate_argnums=donate_argnums), mesh)


class WorldProgram:
  """A jitted per-device program over a batch of worlds (see `per_device`).

  Calling it checks that the batch splits evenly over the mesh's devices,
  then runs the jitted function, traced and compiled under
  `partitioner.scope` of the mesh's devices (GSPMD on several GPUs, where
  Shardy crashed compiling MJX's step).

  Attributes:
    jitted: the `jax.jit` function, for `lower(...)` and ahead-of-time
      compilation.
    mesh: the mesh whose devices share the worlds.
  """

  def __init__(self, jitted, mesh):
    self.jitted = jitted
    self.mesh = mesh

  def __call__(self, *args):
    check_num_worlds(count_worlds(args), self.mesh)
    check_devices(args, self.mesh)
    with partitioner.scope(self.mesh.devices.flat):
      return self.jitted(*args)

  def lower(self, *args):
    """`jax.jit(...).lower(*args)`, after the same check as a call.

    Its `compile()` compiles under the same partitioner as a call, so a
    call after it reuses the compiled program.
    """
    check_num_worlds(count_worlds(args), self.mesh)
    check_devices(args, self.mesh)
    with partitioner.scope(self.mesh.devices.flat):
      return _ScopedLowered(self.jitted.lower(*args), self.mesh)


def check_devices(args, mesh: Mesh) -> None:
  """Refuses arrays committed to other devices than `mesh`'s.

  A `WorldProgram` runs on its mesh's devices. States sharded for another
  mesh (another program's outputs), or actions committed to one device
  while the states are spread over several, would make `jax.jit` fail with
  "Received incompatible devices", naming neither the argument nor the fix.
  Numpy arrays and uncommitted JAX arrays are moved by `jax.jit` and pass.

  Raises:
    ValueError: naming the first such array (its path in the arguments),
      its devices, the mesh's, and `put_worlds`.
  """
  expected = set(mesh.devices.flat)
  leaves = jax.tree_util.tree_flatten_with_path(args)[0]
  for path, x in leaves:
    if (
        not isinstance(x, jax.Array)
        or isinstance(x, jax.core.Tracer)
        or not x.committed
    ):
      continue
    devices = x.sharding.device_set
    if devices != expected:
      ids = lambda ds: sorted(d.id for d in ds)
      where = 'args' + jax.tree_util.keystr(path)
      raise ValueError(
          f'{where} is on devices {ids(devices)}, but this program runs on '
          f'the devices {ids(expected)} of its mesh: place the batch on the '
          'mesh with sharding.put_worlds(tree, mesh) (the states and the '
          "actions alike), or use the program built for the array's mesh "
          '(sharding.batched_step(env, mesh)).'
      )


class _ScopedLowered:
  """A `jax.stages.Lowered` whose `compile` runs in `partitioner.scope`."""

  def __init__(self, lowered, mesh):
    self._lowered = lowered
    self._mesh = mesh

  def compile(self, *args, **kwargs):
    with partitioner.scope(self._mesh.devices.flat):
      return self._lowered.compile(*args, **kwargs)

  def __getattr__(self, name):
    return getattr(self._lowered, name)


# Jitted programs per environment, so that asking again for the same
# environment and mesh returns the same (already compiled) function. The
# programs reach their environment through a weak reference: an entry never
# keeps its own key alive.
_PROGRAMS = weakref.WeakKeyDictionary()


def batched_reset(env, mesh: Mesh | None = None) -> WorldProgram:
  """`reset(keys) -> State`: `jax.vmap(env.reset)`, each device its worlds.

  Args:
    env: an `mjx_composer.Environment`.
    mesh: a mesh from `world_mesh`; default `world_mesh()`.

  Returns:
    A function of a batch of keys (`world_keys`, or any `(n,)` key array)
    returning the batched `State`, sharded over the mesh's world axis. The
    same function is returned for the same environment and mesh.
  """
  return _program(env, 'reset', _mesh(mesh), False)


def batched_step(
    env, mesh: Mesh | None = None, *, donate: bool = False
) -> WorldProgram:
  """`step(states, actions) -> State`: `jax.vmap(env.step)` per device.

  Args:
    env: an `mjx_composer.Environment`.
    mesh: a mesh from `world_mesh`; default `world_mesh()`.
    donate: donate the input states' buffers to the output (saves a copy of
      the batch on GPUs; the states passed in are unusable afterwards).

  Returns:
    A function of a batched `State` and actions of shape
    `(num_worlds, *action_spec().shape)` returning the next `State`, sharded
    over the mesh's world axis. The same function is returned for the same
    environment, mesh and `donate`.
  """
  return _program(env, 'step', _mesh(mesh), bool(donate))


def _program(env, kind, mesh, donate):
  check_impl(env, mesh)
  programs = _PROGRAMS.setdefault(env, {})
  key = (kind, mesh, donate)
  if key not in programs:
    env_ref = weakref.ref(env)

    def batched(*args):
      return jax.vmap(getattr(env_ref(), kind))(*args)

    programs[key] = per_device(
        batched, mesh, donate_argnums=(0,) if donate else ()
    )
  return programs[key]


def check_impl(env, mesh: Mesh) -> None:
  """Refuses to split a MuJoCo Warp batch over several devices.

  MuJoCo Warp keeps the contacts of every world of a batch in one buffer
  (`backend`), which is not per world: cut along the world axis it would
  leave each device a slice of it sized for the whole batch. Not supported
  yet.

  Raises:
    NotImplementedError: `env.impl` is 'warp' and the mesh has several
      devices, with what to do.
  """
  if env.impl == 'warp' and mesh.size > 1:
    raise NotImplementedError(
        f'This environment runs on MuJoCo Warp (impl={env.impl!r}), whose '
        'contact buffer is shared by the whole batch, and cannot be split '
        f'over the {mesh.size} devices of this mesh. Build the environment '
        "with impl='jax' for several devices (on a CUDA GPU, impl=None picks "
        "'warp'), or run Warp on one device (sharding.world_mesh(devices=["
        'jax.devices()[0]])).'
    )


# -- helpers -------------------------------------------------------------------


def _mesh(mesh):
  if mesh is None:
    return world_mesh()
  if not isinstance(mesh, Mesh) or WORLD_AXIS not in mesh.axis_names:
    raise ValueError(
        f"Expected a mesh with a '{WORLD_AXIS}' axis (sharding.world_mesh()), "
        f'got {mesh!r}.'
    )
  if len(mesh.axis_names) != 1:
    raise ValueError(
        f"Expected a 1-D mesh over '{WORLD_AXIS}' (sharding.world_mesh()), "
        f'got axes {mesh.axis_names}.'
    )
  if mesh.size == 0:
    raise ValueError(
        'The mesh has no devices, so no device would run a world: pass a '
        'mesh of at least one device, e.g. sharding.world_mesh() (every '
        'device) or sharding.world_mesh(jax.devices()[:1]).'
    )
  return mesh


def _is_key(x):
  return isinstance(x, jax.Array) and jnp.issubdtype(
      x.dtype, jax.dtypes.prng_key
  )


def _key_data(tree):
  return jax.tree.map(
      lambda x: jax.random.key_data(x) if _is_key(x) else x, tree
  )


def _map_key_data(put, tree):
  """`put` on every array; PRNG keys go through their key data."""

  def leaf(x):
    if _is_key(x):
      impl = jax.random.key_impl(x)
      return jax.random.wrap_key_data(put(jax.random.key_data(x)), impl=impl)
    return put(x)

  return jax.tree.map(leaf, tree)
