"""Math operations on the values of variations.

Mirrors `dm_control.composer.variation.math`: `MathOp(*args, **kwargs)`
evaluates its arguments (any of which may be variations or structures of
them, each with its own subkey) and applies a numpy-like function to them:

* `Log(x)`: elementwise `jnp.log`.
* `Max(x, axis=None)` / `Min(x, axis=None)`: `jnp.max` / `jnp.min`, i.e.
  reductions, like composer's `np.max` / `np.min`. A list argument is stacked
  first, so `Max([a, b])` is the largest of `a` and `b` (reducing all
  elements); use `Max([a, b], axis=0)` for the elementwise maximum of arrays.
* `Norm(x, ord=None, axis=None)`: `jnp.linalg.norm`.

Keyword arguments such as `axis` must stay static (plain Python values).
"""

import jax.numpy as jnp
import numpy as np

from mjx_composer.variation import arrays as arrays_lib
from mjx_composer.variation import bounds as bounds_lib
from mjx_composer.variation import composite
from mjx_composer.variation import printing


class MathOp(composite.CompositeVariation):
  """Applies `_callable` to the evaluated `args` and `kwargs`.

  Positional arguments are converted to jnp arrays (lists are stacked, as
  numpy would); keyword arguments are passed as evaluated.
  """

  _callable = None

  def __init__(self, *args, **kwargs):
    self._args = args
    self._kwargs = kwargs
    # One operand per argument: a lone argument gets the node's key as is.
    self._operands = tuple(args) + tuple(kwargs.values())

  def _apply(self, values, key, initial_value, current_value):
    args = [arrays_lib.as_array(a) for a in values[: len(self._args)]]
    kwargs = dict(zip(self._kwargs, values[len(self._args) :]))
    return type(self)._callable(*args, **kwargs)

  def _eq_fields(self):
    return (self._args, self._kwargs)

  def __repr__(self):
    return printing.format_call(
        type(self).__name__, *self._args, **self._kwargs
    )


class Log(MathOp):
  """Elementwise natural logarithm."""

  _callable = staticmethod(jnp.log)


class _Reduction(MathOp):
  """A max/min reduction whose bounds follow from its argument's bounds."""

  _numpy_reduce = None

  def static_bounds(self):
    # Only the full reduction of one argument: with an `axis`, bounds that
    # broadcast (are smaller than the value) would not reduce the same way.
    if len(self._args) != 1 or self._kwargs:
      return None
    bounds = bounds_lib.static_bounds(self._args[0])
    if bounds is None:
      return None
    reduce = type(self)._numpy_reduce
    # max(x) >= x_i >= low_i for every i, and max(x) <= max_i high_i; min alike.
    return np.asarray(reduce(bounds[0])), np.asarray(reduce(bounds[1]))


class Max(_Reduction):
  """Largest element (`jnp.max`), as composer's `np.max`."""

  _callable = staticmethod(jnp.max)
  _numpy_reduce = staticmethod(np.max)


class Min(_Reduction):
  """Smallest element (`jnp.min`), as composer's `np.min`."""

  _callable = staticmethod(jnp.min)
  _numpy_reduce = staticmethod(np.min)


class Norm(MathOp):
  """Vector or matrix norm (`jnp.linalg.norm`)."""

  _callable = staticmethod(jnp.linalg.norm)
