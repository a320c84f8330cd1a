"""Simulation options that a robot's model asks for, moved to the root spec.

MjSpec does not carry an attached spec's `option` into the composed model:
it keeps the root's, and warns about every option on which the two differ.
Robots loaded from an MJCF file that tunes the solver for MJX (MuJoCo
Playground's models do) read those settings with `take`, keep them on their
own spec (so that a root that adopts them composes without warnings), and
tasks write them on the arena's spec with `put`. MJX's contact limits
(`max_contact_points`, `max_geom_pairs`) travel the same way: MJX reads these
custom numerics by their unprefixed name in the compiled model, so `take`
removes them from the robot's spec (attached, they would be prefixed and
ignored).
"""

# The option attributes a robot's model may set, and MJX's numerics.
OPTION_NAMES = (
    'timestep',
    'integrator',
    'cone',
    'impratio',
    'solver',
    'iterations',
    'ls_iterations',
    'disableflags',
)
MJX_NUMERICS = ('max_contact_points', 'max_geom_pairs')

# Solver caps for small models built in code (the bundled arm's tasks): the
# settings of the bundled humanoid's XML (Playground's HumanoidWalk). With
# MuJoCo's defaults (100 Newton iterations, 50 line-search iterations,
# tolerance 1e-8), MJX's float32 solver runs a batched loop until its
# slowest world meets the tolerance, which here it rarely does, so raw
# MJX steps the reach model about 3x slower on a GPU
# (`docs/performance.md`). MuJoCo's C solver needs 1-6
# iterations on these models, and the caps move their trajectories by less
# than 1e-4 in qpos and 5e-3 in qvel over 2 s
# (`tests/suite/entities/test_simulation_options.py`).
SOLVER_CAPS = {'iterations': 4, 'ls_iterations': 8}


def take(spec):
  """Reads `spec`'s options and takes its MJX numerics off it.

  Returns:
    `{option name: value}` for `OPTION_NAMES`, plus `'numerics': {name:
    data}` for the MJX numerics the spec had (they are deleted from it).
  """
  options = {name: getattr(spec.option, name) for name in OPTION_NAMES}
  numerics = {}
  for numeric in list(spec.numerics):
    if numeric.name in MJX_NUMERICS:
      numerics[numeric.name] = [float(v) for v in numeric.data]
      spec.delete(numeric)
  options['numerics'] = numerics
  return options


def put(root_spec, options):
  """Writes `options` (as `take` returns them) on a root spec."""
  for name, value in options.items():
    if name != 'numerics':
      setattr(root_spec.option, name, value)
  for name, data in options.get('numerics', {}).items():
    existing = [n for n in root_spec.numerics if n.name == name]
    if existing:
      existing[0].data = list(data)
    else:
      root_spec.add_numeric(name=name, data=list(data))
