"""NumPy's random module refusing draws while device hooks are traced.

`refusing_host_randomness`, the one place that patches another package's
public module, and reads NumPy's private global `RandomState`
(`numpy.random.mtrand._rand`): a device hook that draws from NumPy's
random module would bake one host draw into the program as a constant.
With `internals` and `internals_jax`, the only modules that touch another
package's internals (`tests/package/test_layers.py`).
"""

from __future__ import annotations

import contextlib
import functools
import threading
from typing import Any, Callable, Iterator

import numpy as np

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
