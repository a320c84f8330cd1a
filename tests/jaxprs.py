"""Reading traced programs in tests: equations of a jaxpr at any depth."""


def equations(jaxpr):
  """Every equation of `jaxpr`, those of its nested jaxprs (loop bodies,
  branches, inner jits) included, each as often as it appears."""
  for eqn in jaxpr.eqns:
    yield eqn
    for param in eqn.params.values():
      for sub in param if isinstance(param, (list, tuple)) else (param,):
        sub = getattr(sub, 'jaxpr', sub)  # a ClosedJaxpr's
        if hasattr(sub, 'eqns'):
          yield from equations(sub)


def count(jaxpr, *primitives) -> int:
  """How many equations of `jaxpr` (at any depth) apply `primitives`."""
  return sum(eqn.primitive.name in primitives for eqn in equations(jaxpr))
