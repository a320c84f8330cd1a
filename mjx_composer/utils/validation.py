"""Argument checks for constructors, with messages that say what to fix.

Each check raises at construction (on the host, before anything is traced)
with a message naming the argument, the value received and the fix, so a
bad argument never reaches a jitted step where it would turn into NaNs or an
error deep inside JAX. Each returns the checked value (as a float, an int, a
NumPy array or a pair) so a constructor can check and store in one line:

```python notest
self._kp = validation.check_positive('kp', kp, owner='Joystick')
```

`owner` (optional) prefixes the message with the class or function whose
argument it is. Values may be Python numbers, NumPy or concrete JAX arrays;
arrays are checked element-wise. A traced JAX value cannot be checked on the
host: the checks raise a `TypeError` for it rather than pass it silently, so
call them on constructor arguments only.
"""

import numbers
import operator

import numpy as np

__all__ = [
    'check_finite',
    'check_positive',
    'check_nonnegative',
    'check_probability',
    'check_range_pair',
    'check_integer',
    'check_in_range',
    'check_bool',
    'check_choice',
]


def _prefix(owner):
  return f'{owner}: ' if owner else ''


def _error(owner, name, requirement, value, fix):
  message = f'{_prefix(owner)}`{name}` must be {requirement}, got {value!r}.'
  if fix:
    message += f' {fix}'
  return message


def _as_float_array(name, value, owner):
  """`value` as a float NumPy array, or a TypeError naming the argument."""
  if isinstance(value, (bool, np.bool_)):
    raise TypeError(
        _error(owner, name, 'a number', value, 'Pass an int or a float.')
    )
  try:
    array = np.asarray(value)
  except Exception as error:  # A tracer refuses conversion: say so.
    raise TypeError(
        _error(
            owner,
            name,
            'a concrete number or array',
            value,
            'Pass a Python number or a NumPy array (not a traced value).',
        )
    ) from error
  if array.dtype.kind not in 'iuf':
    raise TypeError(
        _error(
            owner,
            name,
            'a real number or an array of them',
            value,
            'Pass an int, a float or a numeric array.',
        )
    )
  return array.astype(float)


def _result(array):
  return float(array) if array.ndim == 0 else array


def check_finite(name, value, *, owner=None, fix=None):
  """Returns `value` as a float (or float array) after checking it is finite.

  Args:
    name: the argument's name, quoted in the message.
    value: a real number or array of them.
    owner: the class or function the argument belongs to, or None.
    fix: a sentence appended to the message, or None for the default.

  Raises:
    TypeError: for a non-numeric value (a bool, a string, a traced value).
    ValueError: for a NaN or infinite element.
  """
  array = _as_float_array(name, value, owner)
  if not np.all(np.isfinite(array)):
    raise ValueError(
        _error(owner, name, 'finite', value, fix or 'Pass a finite number.')
    )
  return _result(array)


def check_positive(name, value, *, owner=None, fix=None):
  """Like `check_finite`, and every element must be > 0."""
  array = _as_float_array(name, value, owner)
  if not np.all(np.isfinite(array) & (array > 0)):
    raise ValueError(
        _error(
            owner,
            name,
            'positive and finite',
            value,
            fix or 'Pass a number > 0.',
        )
    )
  return _result(array)


def check_nonnegative(name, value, *, owner=None, fix=None):
  """Like `check_finite`, and every element must be >= 0."""
  array = _as_float_array(name, value, owner)
  if not np.all(np.isfinite(array) & (array >= 0)):
    raise ValueError(
        _error(
            owner,
            name,
            'non-negative and finite',
            value,
            fix or 'Pass a number >= 0 (0 turns it off).',
        )
    )
  return _result(array)


def check_probability(name, value, *, owner=None, fix=None):
  """Like `check_finite`, and every element must be in [0, 1]."""
  array = _as_float_array(name, value, owner)
  if not np.all(np.isfinite(array) & (array >= 0) & (array <= 1)):
    raise ValueError(
        _error(
            owner,
            name,
            'a probability in [0, 1]',
            value,
            fix or 'Pass a number between 0 and 1.',
        )
    )
  return _result(array)


def check_in_range(name, value, low, high, *, owner=None, fix=None):
  """Like `check_finite`, and every element must be in `[low, high]`."""
  array = _as_float_array(name, value, owner)
  if not np.all(np.isfinite(array) & (array >= low) & (array <= high)):
    raise ValueError(
        _error(
            owner,
            name,
            f'in [{low}, {high}]',
            value,
            fix or f'Pass a number between {low} and {high}.',
        )
    )
  return _result(array)


def check_range_pair(
    name, value, *, owner=None, nonnegative=False, positive=False, fix=None
):
  """Returns `(low, high)` as floats after checking `low <= high`, both finite.

  Args:
    name: the argument's name, quoted in the message.
    value: a sequence of two real numbers.
    owner: the class or function the argument belongs to, or None.
    nonnegative: also require `low >= 0`.
    positive: also require `low > 0`.
    fix: a sentence appended to the message, or None for the default.

  Raises:
    TypeError: for anything but a pair of real numbers.
    ValueError: for a non-finite bound, `low > high`, or a bound below the
      minimum that `nonnegative` or `positive` asks for.
  """
  if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or len(value) != 2:
    raise TypeError(
        _error(
            owner,
            name,
            'a (low, high) pair of numbers',
            value,
            fix or 'Pass two numbers, e.g. (0.1, 0.5).',
        )
    )
  low = check_finite(f'{name}[0]', value[0], owner=owner)
  high = check_finite(f'{name}[1]', value[1], owner=owner)
  if low > high:
    raise ValueError(
        _error(
            owner,
            name,
            'a (low, high) pair with low <= high',
            value,
            fix or f'Swap the bounds: ({high!r}, {low!r}).',
        )
    )
  if positive and low <= 0:
    raise ValueError(
        _error(owner, name, 'positive', value, fix or 'Pass bounds > 0.')
    )
  if nonnegative and low < 0:
    raise ValueError(
        _error(owner, name, 'non-negative', value, fix or 'Pass bounds >= 0.')
    )
  return low, high


def check_integer(name, value, *, owner=None, minimum=None, fix=None):
  """Returns `value` as an int after checking it is one (not a bool or float).

  A float with an integral value (`3.0`) is refused too, as `range()`
  refuses it: silently truncating `2.5` to 2 hides a mistake.

  Args:
    name: the argument's name, quoted in the message.
    value: an int or NumPy integer.
    owner: the class or function the argument belongs to, or None.
    minimum: the smallest value allowed, or None.
    fix: a sentence appended to the message, or None for the default.

  Raises:
    TypeError: for a non-integer value.
    ValueError: for a value below `minimum`.
  """
  if isinstance(value, (bool, np.bool_)) or not isinstance(
      value, (numbers.Integral, np.integer)
  ):
    raise TypeError(
        _error(owner, name, 'an integer', value, fix or 'Pass an int, e.g. 3.')
    )
  value = operator.index(value)
  if minimum is not None and value < minimum:
    raise ValueError(
        _error(
            owner,
            name,
            f'an integer >= {minimum}',
            value,
            fix or f'Pass an int >= {minimum}.',
        )
    )
  return value


def check_bool(name, value, *, owner=None, fix=None):
  """Returns `value` as a bool after checking it is one.

  `bool('false')` is True: a switch given a string, a number or None is
  refused rather than read by its truth value.

  Raises:
    TypeError: for anything but a Python or NumPy bool.
  """
  if not isinstance(value, (bool, np.bool_)):
    raise TypeError(
        _error(owner, name, 'True or False', value, fix or 'Pass a bool.')
    )
  return bool(value)


def check_choice(name, value, choices, *, owner=None, fix=None):
  """Returns `value` after checking it is one of `choices`.

  Raises:
    ValueError: for a value not in `choices` (a TypeError for an unhashable
      one is avoided: the comparison is by equality).
  """
  if not any(value is choice or _equal(value, choice) for choice in choices):
    raise ValueError(
        _error(
            owner,
            name,
            f'one of {tuple(choices)!r}',
            value,
            fix or f'Pass one of {", ".join(map(repr, choices))}.',
        )
    )
  return value


def _equal(value, choice):
  try:
    return bool(value == choice)
  except (TypeError, ValueError):  # e.g. an array compared with a string.
    return False
