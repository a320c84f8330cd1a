"""Every use of JAX's, MJX's and MuJoCo Warp's private internals.

The package needs a few things that JAX, MJX and MuJoCo Warp do not export
(and, while device hooks are traced, NumPy's random module refusing draws:
`refusing_host_randomness`, the one place that patches another package's
public module):
a lowering rule of JAX's Cholesky primitive, JAX's dead-code elimination of
a jaxpr, JAX's partitioner setting, the barrier of JAX's coordination service, MJX's implementation data
(`mjx.Data._impl`, `mjx.Option._impl`), MJX's collision tables, ray-geom
table and quaternion math, and MuJoCo Warp's default constraint rows. This
module is the only one that imports a private module (`jax._src`,
`mujoco.mjx._src`, `mujoco.mjx.third_party.mujoco_warp._src`) or reads an
`_impl` field; every other module calls the names below. When JAX, MuJoCo or MuJoCo Warp is
upgraded, this file is the one to revisit (`tests/package/test_layers.py` keeps
private imports out of the rest of the package).

Each name says what private thing it wraps and why the package needs it.
Written against jax 0.10 and mujoco (MJX) 3.17.
"""

from __future__ import annotations

import contextlib
import functools
import threading
from typing import Any, Callable, Iterator

import jax.numpy as jnp
import numpy as np
from mujoco import mjx

# pylint: disable=protected-access
from jax._src.interpreters import mlir as _mlir
from jax._src.lax import linalg as _linalg
from mujoco.mjx._src import collision_driver as _collision_driver
from mujoco.mjx._src import math as _mjx_math
from mujoco.mjx._src import ray as _mjx_ray
from mujoco.mjx.warp import types as _warp_types

try:  # JAX's own configuration objects, beside the public `jax.config`.
  from jax._src import config as _jax_config
except ImportError:  # pragma: no cover - a JAX that moved it
  _jax_config = None

try:  # JAX's dead-code elimination of a jaxpr: not a public API.
  from jax._src.interpreters import partial_eval as _partial_eval
except ImportError:  # pragma: no cover - a JAX that moved it
  _partial_eval = None


# -- JAX ----------------------------------------------------------------------

# `jax._src.compilation_cache.get_executable_and_time`, which JAX's compiler
# calls (through the module) to load a persistent-cache entry. JAX has no
# public hook for an entry that fails to load: it warns, compiles, and does
# not overwrite the entry (`LRUCache.put` keeps an existing file), so a
# corrupted entry is read and recompiled in every process.
try:
  from jax._src import compilation_cache as _jax_compilation_cache
  from jax._src import lru_cache as _jax_lru_cache
except ImportError:  # pragma: no cover - a JAX that moved them
  _jax_compilation_cache = _jax_lru_cache = None


def remove_unreadable_cache_entries(on_removed: Callable[[str], Any]) -> bool:
  """Makes JAX delete a persistent-cache entry that fails to load.

  Wraps `jax._src.compilation_cache.get_executable_and_time` (once per
  process): when loading an entry raises (a truncated or corrupted file),
  its files are removed and `on_removed(path)` is called, then the error
  propagates to JAX, which warns and compiles as before and now writes a
  fresh entry. Returns False where this JAX lacks those internals.
  """
  module = _jax_compilation_cache
  if module is None or not hasattr(module, 'get_executable_and_time'):
    return False
  original = module.get_executable_and_time
  if getattr(original, 'removes_unreadable_entries', False):
    return True

  def get_executable_and_time(cache_key, compile_options, backend, *args):
    try:
      return original(cache_key, compile_options, backend, *args)
    except Exception:
      cache = module._get_cache(backend)
      folder = getattr(cache, 'path', None) or getattr(cache, '_path', None)
      removed = _remove_entry(folder, cache_key)
      if removed is not None:
        on_removed(removed)
      raise

  get_executable_and_time.removes_unreadable_entries = True
  module.get_executable_and_time = get_executable_and_time
  return True


# `jax._src.compilation_cache.get_file_cache`, which JAX calls once per
# process to make the persistent cache object (a `jax._src.lru_cache.LRUCache`,
# maybe inside a `VerificationCache`). An entry's file name is its key, and
# nothing inside the file says which program it holds: JAX loads whatever a
# file of that name holds, and an entry renamed, copied or swapped with
# another one loads another program, which fails far from the cause (an
# assertion in `safe_zip` when the outputs are counted) or, where the two
# programs take and return the same shapes, silently runs the wrong one.

# What a bound entry starts with, followed by its key and a NUL byte.
CACHE_KEY_HEADER = b'mjx_composer persistent cache entry, key: '


def _entry_key(raw: bytes) -> str | None:
  """The key a bound entry was written under, or None for an unbound one."""
  if not raw.startswith(CACHE_KEY_HEADER):
    return None
  end = raw.find(b'\0', len(CACHE_KEY_HEADER))
  if end < 0:
    return None
  try:
    return raw[len(CACHE_KEY_HEADER) : end].decode('utf-8')
  except UnicodeDecodeError:
    return None


def _remove_entry(folder, cache_key: str) -> str | None:
  """Deletes `cache_key`'s entry files in `folder`; returns the entry's path."""
  if folder is None or not cache_key or _jax_lru_cache is None:
    return None
  entry = folder / f'{cache_key}{_jax_lru_cache._CACHE_SUFFIX}'
  atime = folder / f'{cache_key}{_jax_lru_cache._ATIME_SUFFIX}'
  removed = None
  if entry.exists():
    entry.unlink()
    removed = str(entry)
  if atime.exists():
    atime.unlink()
  return removed


if _jax_compilation_cache is not None and hasattr(
    _jax_compilation_cache, 'CacheInterface'
):

  class _KeyBoundCache(_jax_compilation_cache.CacheInterface):
    """A file cache whose entries each carry the key they were written under.

    `put` writes `CACHE_KEY_HEADER + key + NUL` before JAX's bytes; `get`
    returns JAX's bytes only when the entry names the key it is read under.
    Any other entry (one renamed, copied or swapped from another key, or
    written without the header by a JAX that did not bind its entries) is
    removed, reported to `on_removed(path, key_it_holds_or_None)` and read
    as a miss: JAX compiles the program and writes a bound entry.
    """

    def __init__(self, base, on_removed):
      self._base_cache = base
      self._on_removed = on_removed

    @property
    def _path(self):  # pytype: disable=signature-mismatch
      return self._base_cache._path

    @_path.setter
    def _path(self, value):
      self._base_cache._path = value

    @property
    def path(self):
      return getattr(self._base_cache, 'path', self._base_cache._path)

    def get(self, key: str):
      raw = self._base_cache.get(key)
      if raw is None:
        return None
      holds = _entry_key(raw)
      if holds == key:
        return raw[len(CACHE_KEY_HEADER) + len(key.encode('utf-8')) + 1 :]
      removed = _remove_entry(self.path, key)
      if removed is not None:
        self._on_removed(removed, holds)
      return None

    def put(self, key: str, value: bytes):
      self._base_cache.put(
          key, CACHE_KEY_HEADER + key.encode('utf-8') + b'\0' + value
      )

    def clear(self):
      clear = getattr(self._base_cache, 'clear', None)
      if clear is not None:
        clear()

else:  # pragma: no cover - a JAX that moved them
  _KeyBoundCache = None


def bind_cache_entries_to_keys(
    on_removed: Callable[[str, str | None], Any],
) -> bool:
  """Makes every persistent-cache entry name the key it was written under.

  Wraps `jax._src.compilation_cache.get_file_cache` (once per process), so
  the cache JAX makes when it first compiles with a cache folder writes the
  key into each entry and refuses an entry that names another key (or
  none): such an entry is removed, `on_removed(path, key_it_holds)` is
  called (`key_it_holds` is None for an entry without a key) and JAX
  compiles the program afresh, as for an entry it never had. Call it before
  the first compilation with the cache folder set. Returns False where this
  JAX lacks those internals (entries are then read as JAX reads them).
  """
  module = _jax_compilation_cache
  if (
      module is None
      or _KeyBoundCache is None
      or not hasattr(module, 'get_file_cache')
  ):
    return False
  original = module.get_file_cache
  if getattr(original, 'binds_entries_to_keys', False):
    return True

  def get_file_cache(path):
    made = original(path)
    if made is None:
      return None
    cache, folder = made
    inner = getattr(cache, '_base_cache', None)
    if inner is not None:  # a VerificationCache compares JAX's own bytes
      cache._base_cache = _KeyBoundCache(inner, on_removed)
    else:
      cache = _KeyBoundCache(cache, on_removed)
    return cache, folder

  get_file_cache.binds_entries_to_keys = True
  module.get_file_cache = get_file_cache
  return True


# `jax._src.interpreters.mlir.lower_fun`: turns a JAX function into a
# lowering rule. `cpu_linalg` lowers Cholesky to plain XLA loops with it;
# JAX has no public way to replace a primitive's lowering.
lower_fun = _mlir.lower_fun

# `jax._src.lax.linalg.cholesky_p`: JAX's Cholesky primitive, whose CPU
# lowering `cpu_linalg` replaces.
cholesky_p = _linalg.cholesky_p

# `jax._src.lax.linalg._cholesky_cpu_lowering`: JAX's own CPU lowering of
# Cholesky (a LAPACK call), which `cpu_linalg.enable(enabled=False)` puts
# back.
lapack_cholesky_cpu_lowering = _linalg._cholesky_cpu_lowering


def wait_for_processes(barrier: str, timeout_s: float) -> None:
  """Blocks until every `jax.distributed` process reaches `barrier`.

  The coordination service's barrier (`jax._src.distributed`'s client),
  with a timeout of our choosing: the public `multihost_utils` barrier is a
  collective, which JAX's CPU collectives (Gloo) give up on when another
  process is more than 30 s late, e.g. still compiling. A single process
  returns at once.
  """
  # pylint: disable=g-import-not-at-top
  from jax._src import distributed as _distributed

  # pylint: enable=g-import-not-at-top
  client = _distributed.global_state.client
  if client is None:
    return
  client.wait_at_barrier(barrier, int(timeout_s * 1000))


def register_cpu_lowering(primitive, rule) -> None:
  """`jax._src.interpreters.mlir.register_lowering(..., platform='cpu')`.

  Makes `rule` the CPU lowering of `primitive` for programs lowered from
  now on (`cpu_linalg`).
  """
  _mlir.register_lowering(primitive, rule, platform='cpu')


def shardy_partitioner_state():
  """JAX's `jax_use_shardy_partitioner` state, or None where it is gone.

  `jax._src.config.use_shardy_partitioner`: a context manager that selects
  Shardy (True) or GSPMD (False) for what is traced and compiled inside it.
  `jax.config.update` sets it for the whole process; `partitioner.scope`
  needs it for one block only, which only the private object offers. None
  on a JAX without the setting (GSPMD removed).
  """
  if _jax_config is None:
    return None
  return getattr(_jax_config, 'use_shardy_partitioner', None)


# `jax._src.interpreters.partial_eval.dce_jaxpr`, or None on a JAX without
# it: dead-code elimination of a jaxpr given which outputs are used, what
# `runtime.data_reads` uses to tell which `mjx.Data` fields a traced function
# reads (without it, every field counts as read).
dce_jaxpr: Callable[..., Any] | None = getattr(_partial_eval, 'dce_jaxpr', None)


# -- MJX ------------------------------------------------------------------------


def data_impl(data):
  """`data._impl`: the implementation data of an `mjx.Data`.

  A `DataJAX` ('jax') or `DataWarp` ('warp'). MJX 3.17 keeps some fields
  only there and has no public accessor for them: the tendon Jacobian
  (`ten_J`), the actuator moments (`actuator_moment`), the constraint
  Jacobian (`efc_J`); on 'warp', the buffer sizes and overflow flags
  (`naconmax`, `njmax`, `nacon`, `overflow`). MJX's deprecation message for
  `Data.<field>` points there.
  """
  return data._impl


def replace_data_impl(data, **fields):
  """`data` with `fields` of its implementation data (`data._impl`) replaced."""
  return data.replace(_impl=data._impl.replace(**fields))


def option_impl(option):
  """`option._impl`: the implementation options of an `mjx.Option`.

  On 'warp', MuJoCo Warp's options, among them `warn_overflow` (which
  overflows its kernels print a warning for); MJX has no public accessor.
  """
  return option._impl


def replace_option_impl(option, **fields):
  """`option` with `fields` of its implementation options replaced."""
  return option.replace(_impl=option._impl.replace(**fields))


def collision_pair_groups(mj_model) -> dict:
  """`mujoco.mjx._src.collision_driver._geom_groups(mj_model)`.

  MJX's static collision pairs grouped by narrow-phase function: the pairs
  `mjx.collision` tests (contype/conaffinity, exclusions, `<pair>`s and
  parent filtering as MuJoCo's), keyed by the function's key. The contact
  queries of `initializers.contacts` test a subset of them with MJX's own
  functions; MJX exports neither the table nor the functions.
  """
  return _collision_driver._geom_groups(mj_model)


def colliding_geom_pairs(mj_model) -> list[tuple[int, int]]:
  """`mujoco.mjx._src.collision_driver.geom_pairs(mj_model)`'s geom ids.

  Every pair of geoms MJX's JAX implementation tests for contact, after
  contype/conaffinity, exclusions and parent filtering, `<pair>`s included.
  """
  return [
      (int(g1), int(g2)) for g1, g2, _ in _collision_driver.geom_pairs(mj_model)
  ]


def has_collision_function(type1: int, type2: int) -> bool:
  """Whether MJX's JAX implementation collides geoms of these two types."""
  return bool(_collision_driver.has_collision_fn(type1, type2))


def contact_dims(mj_model):
  """`mujoco.mjx._src.collision_driver.make_condim(mj_model)`.

  The dimension of every contact MJX's JAX implementation allocates (one
  entry per potential contact, static): its solver's elliptic cone runs
  only where there is at least one and none has dimension 1, and MJX names
  neither case when it fails (`environment` chooses the cone from this).
  """
  return _collision_driver.make_condim(mj_model)


def collision_function(key):
  """`mujoco.mjx._src.collision_driver._COLLISION_FUNC[key.types]`.

  The narrow-phase function MJX runs on the pairs of `key`'s group
  (`collision_pair_groups`): `fn(model, data, key, pairs)` returns the
  signed distances, positions and frames of their contacts.
  """
  return _collision_driver._COLLISION_FUNC[key.types]


# `mujoco.mjx._src.math`: MJX's quaternion functions, so that poses composed
# outside `mjx.kinematics` (`initializers.contacts.rigid_geom_poses`) round
# as MJX's own kinematics do.
quat_normalize = _mjx_math.normalize
quat_rotate = _mjx_math.rotate
quat_mul = _mjx_math.quat_mul
quat_to_mat = _mjx_math.quat_to_mat


def _ray_cylinder(size, pnt, vec):
  """Distance along `vec` from `pnt` to a cylinder's surface (`inf`: none).

  The cylinder's frame: radius `size[0]`, half-height `size[1]` along z. As
  MuJoCo's `mju_rayGeom`: the nearest intersection at a distance >= 0 with
  the round side (between the flat sides) or a flat side (within the
  radius), so a ray from inside meets the surface on its way out.
  """
  radius, half_height = size[0], size[1]
  minval = _mjx_ray.mujoco.mjMINVAL
  # Round side: |pnt_xy + t vec_xy| = radius, i.e. a t^2 + 2 b t + c = 0.
  a = vec[0] * vec[0] + vec[1] * vec[1]
  b = vec[0] * pnt[0] + vec[1] * pnt[1]
  c = pnt[0] * pnt[0] + pnt[1] * pnt[1] - radius * radius
  det = b * b - a * c
  root = jnp.sqrt(jnp.maximum(det, 0.0))
  safe_a = jnp.where(a < minval, 1.0, a)
  side = jnp.stack([(-b - root) / safe_a, (-b + root) / safe_a])
  side_hit = (det >= minval) & (a >= minval) & (side >= 0)
  side_hit &= jnp.abs(pnt[2] + side * vec[2]) <= half_height
  # Flat sides: z = +-half_height, within the radius.
  safe_vz = jnp.where(jnp.abs(vec[2]) < minval, 1.0, vec[2])
  caps = (jnp.stack([half_height, -half_height]) - pnt[2]) / safe_vz
  xy = pnt[:2] + caps[:, None] * vec[:2]
  caps_hit = (jnp.abs(vec[2]) >= minval) & (caps >= 0)
  caps_hit &= jnp.sum(xy * xy, axis=-1) <= radius * radius
  return jnp.min(
      jnp.concatenate(
          [
              jnp.where(side_hit, side, jnp.inf),
              jnp.where(caps_hit, caps, jnp.inf),
          ]
      )
  )


def add_missing_ray_functions() -> None:
  """Fills `mujoco.mjx._src.ray._RAY_FUNC` where MJX lacks a geom type.

  MJX's table of ray-geom functions serves `mjx.ray` and the touch sensor,
  which counts the contacts whose force ray meets its site's volume. MJX
  3.17 has no cylinder entry, so a touch sensor on a cylinder site (as
  composer's tutorial builds its button) fails to trace with a `KeyError`;
  this adds `_ray_cylinder`, MuJoCo's semantics. An entry MJX has is never
  replaced.
  """
  _mjx_ray._RAY_FUNC.setdefault(_mjx_ray.GeomType.CYLINDER, _ray_cylinder)


# What a port of dm_control code meets on MJX's classes, and what to use.
CONTACT_INDEXING_MESSAGE = (
    "MJX's contact list (`physics.data.contact`) cannot be indexed or "
    "iterated as dm_control's `physics.data.contact[:physics.data.ncon]`: "
    'it holds a fixed number of candidate slots per world, most of them not '
    'touching, and a Python loop or `if` cannot branch on traced values. Ask '
    'the question as one function of the physics: '
    '`mjx_composer.observation.contacts.between(physics, geoms_a, geoms_b)` '
    '(`.touching`, `.count`, `.normal_force`, `.force`; `geoms_b=None`: '
    'anything else) or, per row of geoms, '
    '`mjx_composer.observation.contact_sensor`.'
)
MUJOCO_POINTER_MESSAGE = (
    "{kind} is MJX's `mjx.{kind}`, not dm_control's wrapper of MuJoCo's "
    "Mj{kind}: it has no `ptr`, and MuJoCo's C functions (`mujoco.mj_*`, "
    "dm_control's `mjlib`) cannot run on a traced world. Use MJX's function "
    '(`mujoco.mjx`), a binding (`physics.bind(...)`), or, for what the '
    'compiled model knows (names, ids, sizes, defaults), `physics.mj_model`: '
    'the host MjModel shared by every world, read while tracing.'
)


def explain_dm_control_idioms() -> None:
  """Clear errors for dm_control idioms on MJX's `Contact`, `Model` and
  `Data`, where Python's own errors say nothing of what to use.

  * `mjx.Contact` (`physics.data.contact`, through MJX's deprecated
    forwarding to `data._impl.contact`) gets a `__getitem__` that raises
    a `TypeError` (`CONTACT_INDEXING_MESSAGE`). Python's iteration falls
    back to it, so `for c in physics.data.contact` and `contact[:ncon]`
    raise it too; MJX defines neither, and `Contact` stays a plain pytree
    (not an `Iterable` to `isinstance`).
  * `mjx.Model.ptr` and `mjx.Data.ptr` (dm_control's way to hand MuJoCo's
    C functions the model and data) raise an `AttributeError` that says
    what to use (`MUJOCO_POINTER_MESSAGE`); `hasattr` stays False. MJX's
    own `__getattr__` answers every other missing name as before.

  A name MJX defines itself is never replaced; calling this again does
  nothing.
  """
  if '__getitem__' not in vars(mjx.Contact):

    def refuse_indexing(self, key):
      del self, key
      raise TypeError(CONTACT_INDEXING_MESSAGE)

    mjx.Contact.__getitem__ = refuse_indexing
  for cls in (mjx.Model, mjx.Data):
    original = vars(cls).get('__getattr__')
    if 'ptr' in vars(cls) or getattr(original, '_explains_ptr', False):
      continue
    cls.__getattr__ = _explaining_ptr(cls.__name__, original)


def _explaining_ptr(kind: str, original):
  """`original` (a class's `__getattr__`, or None), answering `ptr` with
  `MUJOCO_POINTER_MESSAGE`."""

  def __getattr__(self, name):  # pylint: disable=invalid-name
    if name == 'ptr':
      raise AttributeError(MUJOCO_POINTER_MESSAGE.format(kind=kind))
    if original is None:
      raise AttributeError(
          f"'{type(self).__name__}' object has no attribute '{name}'"
      )
    return original(self, name)

  __getattr__._explains_ptr = True  # pylint: disable=protected-access
  return __getattr__


# -- NumPy ----------------------------------------------------------------------

# `numpy.random`'s module-level draws are bound methods of one hidden, legacy
# `RandomState` (`numpy.random.mtrand._rand`); `seed`, `ranf` and `sample` are
# functions that use it. NumPy has no hook for "a draw happened": while a
# device hook is traced these names are replaced (for the tracing thread only)
# by functions that raise, and the constructors of new generators with them.
_GLOBAL_RANDOM_STATE = np.random.mtrand._rand
_NOT_DRAWS = ('get_state', 'set_state')
_HOST_RANDOM_FUNCTIONS = tuple(
    sorted(
        name
        for name in dir(np.random)
        if getattr(getattr(np.random, name), '__self__', None)
        is _GLOBAL_RANDOM_STATE
        and name not in _NOT_DRAWS
    )
    + [name for name in ('seed', 'ranf', 'sample') if hasattr(np.random, name)]
)
_HOST_RANDOM_CONSTRUCTORS = ('default_rng', 'RandomState', 'Generator')

_host_random_lock = threading.Lock()
_host_random_thread = threading.local()  # .refusals: a stack of callables
_host_random_users = 0
_host_random_originals: dict[str, Any] = {}


def _refusals() -> list:
  stack = getattr(_host_random_thread, 'refusals', None)
  if stack is None:
    stack = _host_random_thread.refusals = []
  return stack


def _refusing_function(name: str, original):
  """`original`, refused in a thread that is tracing a device hook."""

  @functools.wraps(original)
  def refuse(*args, **kwargs):
    stack = _refusals()
    if stack:
      raise stack[-1](f'numpy.random.{name}')
    return original(*args, **kwargs)

  refuse.refuses_host_randomness = True
  return refuse


class _RefusingClassType(type):
  """The metaclass of a stand-in for `numpy.random.RandomState`/`Generator`.

  Calling the stand-in (making a generator) is refused in a thread that is
  tracing a device hook and makes the real class elsewhere; `isinstance`
  and `issubclass` answer as for the real class, so code that checks for a
  numpy generator (e.g. to refuse one as a key) keeps working.
  """

  def __call__(cls, *args, **kwargs):
    stack = _refusals()
    if stack:
      raise stack[-1](f'numpy.random.{cls._original.__name__}(...)')
    return cls._original(*args, **kwargs)

  def __instancecheck__(cls, instance):
    return isinstance(instance, cls._original)

  def __subclasscheck__(cls, subclass):
    if isinstance(subclass, _RefusingClassType):
      subclass = subclass._original
    return issubclass(subclass, cls._original)


def _refusing_class(original):
  return _RefusingClassType(
      original.__name__,
      (),
      {
          '_original': original,
          '__doc__': original.__doc__,
          '__module__': original.__module__,
      },
  )


def _install_host_random_refusals() -> None:
  for name in _HOST_RANDOM_FUNCTIONS + _HOST_RANDOM_CONSTRUCTORS:
    original = getattr(np.random, name)
    _host_random_originals[name] = original
    if isinstance(original, type):
      setattr(np.random, name, _refusing_class(original))
    else:
      setattr(np.random, name, _refusing_function(name, original))


def _remove_host_random_refusals() -> None:
  for name, original in _host_random_originals.items():
    setattr(np.random, name, original)
  _host_random_originals.clear()


def _global_random_state():
  return _GLOBAL_RANDOM_STATE.get_state(legacy=False)


def _same_random_state(before, after) -> bool:
  """Whether two `get_state(legacy=False)` of a `RandomState` are equal: the
  Mersenne Twister's key and position, and the cached Gaussian that every
  other `normal` draw takes instead of moving the position."""
  return (
      before['state']['pos'] == after['state']['pos']
      and np.array_equal(before['state']['key'], after['state']['key'])
      and before['has_gauss'] == after['has_gauss']
      and before['gauss'] == after['gauss']
  )


@contextlib.contextmanager
def refusing_host_randomness(
    refusal: Callable[[str], Exception],
) -> Iterator[None]:
  """Within the block, this thread's draws from NumPy's random module raise.

  Made for the tracing of a device hook, where a host draw runs once, when
  the hook is traced, and its value is then a constant of the compiled
  program: the same in every world and every episode. Within the block,
  in the thread that entered it:

  * every module-level draw (`numpy.random.uniform`, `normal`, `randint`,
    `rand`, `choice`, `shuffle`, ..., and `seed`: NumPy's legacy global
    `RandomState`) and every new generator (`numpy.random.default_rng`,
    `RandomState(...)`, `Generator(...)`) raises `refusal(what)`, where
    `what` names the call (e.g. `'numpy.random.uniform'`);
  * where the process runs no other Python thread, a draw from the global
    `RandomState` through a name bound before the block (`from numpy.random
    import uniform`) is found when the block ends (its state moved) and
    raises `refusal(...)` too.

  Other threads draw as usual; blocks nest (the innermost's `refusal`
  answers). `isinstance(x, numpy.random.RandomState)` (and `Generator`)
  answers as before. The names are patched on `numpy.random` while any
  thread is in a block, and restored when the last one leaves.
  """
  global _host_random_users
  with _host_random_lock:
    if _host_random_users == 0:
      _install_host_random_refusals()
    _host_random_users += 1
  stack = _refusals()
  stack.append(refusal)
  before = _global_random_state()
  try:
    yield
    if threading.active_count() == 1 and not _same_random_state(
        before, _global_random_state()
    ):
      raise refusal(
          "numpy.random's global RandomState (through a name bound before "
          'the hook ran, such as `from numpy.random import uniform`)'
      )
  finally:
    stack.pop()
    with _host_random_lock:
      _host_random_users -= 1
      if _host_random_users == 0:
        _remove_host_random_refusals()


# -- MuJoCo Warp ----------------------------------------------------------------


def warp_default_njmax(mj_model) -> int:
  """MuJoCo Warp's own estimate of the constraint rows per world.

  `mujoco.mjx.third_party.mujoco_warp._src.io._default_njmax(mj_model)`:
  what `make_data` allocates unless told; `backend.default_njmax` takes the
  larger of it and MJX's JAX count. Imported here, not at the top: MuJoCo
  Warp imports only where `warp-lang` is installed.
  """
  from mujoco.mjx.third_party.mujoco_warp._src import io as warp_io  # pylint: disable=g-import-not-at-top

  return int(warp_io._default_njmax(mj_model))


def warp_model_batch_dims() -> dict[str, bool]:
  """`mujoco.mjx.warp.types._BATCH_DIM['Model']`: which fields vary per world.

  `{model field: whether it has a batch dimension}` for the fields MuJoCo
  Warp reads: `backend.check_per_world_fields` refuses per-world values of
  the others. MJX keeps the table private.
  """
  return _warp_types._BATCH_DIM['Model']
