"""How variations print: a node's `repr` from its construction arguments.

`format_call('Uniform', low, high=...)` gives `Uniform(low, high=...)`, its
variation arguments printed by their own `repr` (or `str`, `format_value`),
so that an expression prints as it was written.
"""

from mjx_composer.variation import base


def format_value(value, use_str=False) -> str:
  """Text for an argument in a variation's repr (str of variations if asked)."""
  if isinstance(value, base.Variation):
    return str(value) if use_str else repr(value)
  return repr(value)


def format_call(name, *args, **kwargs) -> str:
  """`Name(arg, key=value, ...)` with variation arguments printed by repr."""
  parts = [format_value(a) for a in args]
  parts += [f"{k}={format_value(v)}" for k, v in kwargs.items()]
  return f"{name}({', '.join(parts)})"
