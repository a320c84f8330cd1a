"""The layer rule of ARCHITECTURE.md: which modules may import which.

Every module of the package is parsed with `ast` (no import runs), and each
of its imports, at module level or inside a function, is checked:

* against its layer's allowed layers (`ALLOWED`);
* for private modules (a dotted path with a `_src` part: `jax._src`,
  `mujoco.mjx._src`, MuJoCo Warp's and warp's `_src`), which only
  `platform/internals.py` may import;
* for reads of MJX's private `_impl` fields (`x._impl` on anything but
  `self`/`cls`), which only the `platform/internals*` modules may do;
* for branches on the MJX implementation's name outside `platform/`:
  calls of `is_warp`, comparisons with 'jax' or 'warp', reads of
  `mjx.Impl.JAX`/`mjx.Impl.WARP`. The rest of the package asks its
  `platform.backend.Backend` what it supports and has it run what differs;
* for reads of stack frames (`sys._getframe`, `inspect.currentframe`,
  `.f_locals`, `.f_back`) and assignments to attributes of other packages'
  modules and classes (`brax_module.name = ...`, `setattr(np.random, ...)`),
  which only the `platform/internals*` modules may do: the rest of the
  package uses other libraries through their public APIs.
"""

from __future__ import annotations

import ast
import dataclasses
import pathlib

import mjx_composer

PACKAGE = 'mjx_composer'
ROOT = pathlib.Path(mjx_composer.__file__).resolve().parent

# The layer of each module: the first matching prefix (a subpackage) or
# module name, after `PACKAGE.`.
LAYER_OF = {
    'platform': 'platform',
    'utils': 'utils',
    'model': 'model',
    # Authoring: composer's API, what users subclass and bind.
    'arena': 'authoring',
    'constants': 'authoring',
    'define': 'authoring',
    'entity': 'authoring',
    'initializer': 'authoring',
    'robot': 'authoring',
    'task': 'authoring',
    'physics': 'authoring',
    'observation': 'authoring',
    'variation': 'authoring',
    'initializers': 'authoring',
    'compiler': 'authoring',
    'runtime': 'runtime',
    'environment': 'environment',
    'host': 'host',
    'adapters': 'adapters',
    'training': 'training',
    # Content: robots, props, arenas, tasks and the locomotion kit, built
    # with the authoring API like a user's own.
    'suite': 'content',
    # Entry points: may import anything.
    'cli': 'entry',
    '__main__': 'entry',
    '': 'entry',  # the package itself (`import mjx_composer`)
}

_BELOW_AUTHORING = {'authoring', 'model', 'platform', 'utils'}

# The layers each layer may import (its own included).
ALLOWED = {
    'platform': {'platform'},
    'utils': {'utils'},
    'model': {'model', 'platform', 'utils'},
    'authoring': _BELOW_AUTHORING,
    'runtime': {'runtime'} | _BELOW_AUTHORING,
    'environment': {'environment', 'runtime'} | _BELOW_AUTHORING,
    'host': {'host', 'environment', 'runtime'} | _BELOW_AUTHORING,
    'adapters': {'adapters', 'environment', 'runtime'} | _BELOW_AUTHORING,
    'content': {'content'} | _BELOW_AUTHORING,
    # Training from the command line: runs Brax through the adapter, renders
    # with host/, builds tasks by name through the registry.
    'training': {
        'training',
        'host',
        'adapters',
        'content',
        'environment',
        'runtime',
    }
    | _BELOW_AUTHORING,
    'entry': set(LAYER_OF.values()),
}

# Modules allowed more than their layer: {module: extra layers}.
EXCEPTIONS = {
    # The registry of the suite's tasks builds their environments by name.
    'mjx_composer.suite.tasks.registry': {'environment'},
}

# The modules that may import private modules and read `_impl`: the JAX,
# NumPy and MJX/MuJoCo Warp internals, each in its own module.
INTERNALS = 'mjx_composer.platform.internals'
INTERNALS_MODULES = frozenset(
    {
        INTERNALS,
        'mjx_composer.platform.internals_jax',
        'mjx_composer.platform.internals_numpy',
    }
)

# The implementations' names, which only `platform/` may branch on.
IMPL_NAMES = frozenset({'jax', 'warp'})


def layer_of(module: str) -> str | None:
  """The layer of a module of the package (None: not classified)."""
  rest = module[len(PACKAGE) + 1 :] if module != PACKAGE else ''
  head = rest.split('.')[0]
  return LAYER_OF.get(head)


def module_name(path: pathlib.Path, root: pathlib.Path = ROOT) -> str:
  parts = list(path.relative_to(root).with_suffix('').parts)
  if parts[-1] == '__init__':
    parts = parts[:-1]
  return '.'.join([PACKAGE] + parts)


def package_modules(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
  return {module_name(p, root): p for p in sorted(root.rglob('*.py'))}


@dataclasses.dataclass(frozen=True)
class Import:
  line: int
  # The dotted path imported; `from a import b`: `a.b`, which names module
  # `a.b` or, where `b` is not a module, `a` (`_target`).
  name: str


def imports(source: str, module: str, is_package: bool = False):
  """Every import of `source`, module-level or inside functions."""
  found = []
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, ast.Import):
      found.extend(Import(node.lineno, a.name) for a in node.names)
    elif isinstance(node, ast.ImportFrom):
      base = node.module or ''
      if node.level:  # relative: resolve against the importing package
        package = module.split('.') if is_package else module.split('.')[:-1]
        package = package[: len(package) - (node.level - 1)]
        base = '.'.join(package + ([base] if base else []))
      found.extend(Import(node.lineno, f'{base}.{a.name}') for a in node.names)
  return found


def _impl_reads(source: str):
  """Lines that read an `_impl` attribute of something other than self/cls."""
  lines = []
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, ast.Attribute) and node.attr == '_impl':
      owner = node.value
      if not (isinstance(owner, ast.Name) and owner.id in ('self', 'cls')):
        lines.append(node.lineno)
  return lines


def _names_an_impl(node) -> bool:
  """Whether `node` is the string 'jax' or 'warp', or a collection of one."""
  if isinstance(node, ast.Constant):
    return node.value in IMPL_NAMES
  if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
    return any(_names_an_impl(e) for e in node.elts)
  return False


def backend_branches(source: str) -> list[tuple[int, str]]:
  """`(line, what)` for each test of the MJX implementation's name.

  Calls of `is_warp`, comparisons with 'jax' or 'warp' (`impl == 'warp'`,
  `impl in ('jax', 'warp')`), and reads of `Impl.JAX`/`Impl.WARP` (as
  `mjx.Impl.WARP` or `Impl.WARP`).
  """
  found = []
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, ast.Call):
      func = node.func
      name = (
          func.attr
          if isinstance(func, ast.Attribute)
          else (func.id if isinstance(func, ast.Name) else None)
      )
      if name == 'is_warp':
        found.append((node.lineno, 'calls is_warp'))
    elif isinstance(node, ast.Compare):
      if any(_names_an_impl(n) for n in [node.left, *node.comparators]):
        found.append((node.lineno, "compares with 'jax'/'warp'"))
    elif isinstance(node, ast.Attribute) and node.attr in ('JAX', 'WARP'):
      owner = node.value
      if (isinstance(owner, ast.Attribute) and owner.attr == 'Impl') or (
          isinstance(owner, ast.Name) and owner.id == 'Impl'
      ):
        found.append((node.lineno, f'reads Impl.{node.attr}'))
  return sorted(set(found))


_FRAME_READS = frozenset({'_getframe', 'currentframe', 'f_locals', 'f_back'})


def _foreign_names(tree) -> set[str]:
  """The names that imports of other packages bind (modules, classes, ...)."""
  names = set()
  for node in ast.walk(tree):
    if isinstance(node, ast.Import):
      for a in node.names:
        if a.name.split('.')[0] != PACKAGE:
          names.add(a.asname or a.name.split('.')[0])
    elif isinstance(node, ast.ImportFrom):
      if not node.level and (node.module or '').split('.')[0] != PACKAGE:
        names.update(a.asname or a.name for a in node.names)
  return names


def _base_name(node) -> str | None:
  """`a` of `a.b.c`; None for anything but a dotted name."""
  while isinstance(node, ast.Attribute):
    node = node.value
  return node.id if isinstance(node, ast.Name) else None


def patches(source: str) -> list[tuple[int, str]]:
  """`(line, what)` for each stack frame read and each attribute of another
  package's module or class assigned (`=`, `+=`, `setattr`)."""
  tree = ast.parse(source)
  foreign = _foreign_names(tree)
  found = []
  for node in ast.walk(tree):
    name = getattr(node, 'attr', getattr(node, 'id', None))
    if isinstance(node, (ast.Attribute, ast.Name)) and name in _FRAME_READS:
      found.append((node.lineno, f'reads a stack frame ({name})'))
    targets = []
    if isinstance(node, ast.Assign):
      targets = node.targets
    elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
      targets = [node.target]
    elif (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == 'setattr'
        and node.args
    ):
      targets = [ast.Attribute(node.args[0], '?', lineno=node.lineno)]
    for target in targets:
      base = _base_name(target) if isinstance(target, ast.Attribute) else None
      if base in foreign:
        found.append(
            (node.lineno, f"assigns an attribute of another package's {base}")
        )
  return sorted(set(found))


def _target(name: str, modules) -> str | None:
  """The package module an import names (the longest known prefix)."""
  while name:
    if name in modules:
      return name
    name = name.rpartition('.')[0]
  return None


def violations(
    module: str, source: str, modules, is_package: bool = False
) -> list[str]:
  """What in `source` (the text of `module`) breaks the layer rule."""
  problems = []
  layer = layer_of(module)
  if layer is None:
    return [
        f'{module}: in no layer; add it to LAYER_OF in '
        'tests/package/test_layers.py and to the Layers table of ARCHITECTURE.md'
    ]
  allowed = ALLOWED[layer] | EXCEPTIONS.get(module, set())
  reported = set()
  for imp in imports(source, module, is_package):
    if '_src' in imp.name.split('.') and module not in INTERNALS_MODULES:
      key = (imp.line, 'private')
      if key not in reported:
        reported.add(key)
        problems.append(
            f'{module}:{imp.line}: imports the private module {imp.name}; '
            f'only {INTERNALS} may (add a named function there)'
        )
      continue
    if imp.name != PACKAGE and not imp.name.startswith(PACKAGE + '.'):
      continue
    target = _target(imp.name, modules)
    if target is None or target == module:
      continue
    target_layer = layer_of(target)
    if target_layer not in allowed:
      key = (imp.line, target)
      if key not in reported:
        reported.add(key)
        problems.append(
            f'{module}:{imp.line}: {layer} imports {target} '
            f'({target_layer}); {layer} may import {sorted(allowed)}'
        )
  if module not in INTERNALS_MODULES:
    for line in _impl_reads(source):
      problems.append(
          f"{module}:{line}: reads MJX's private `_impl`; only {INTERNALS} "
          'may (internals.data_impl, internals.option_impl, ...)'
      )
  if module not in INTERNALS_MODULES:
    for line, what in patches(source):
      problems.append(
          f'{module}:{line}: {what}; use the public API (only the '
          "platform/internals*.py modules may touch other packages' "
          'internals)'
      )
  if layer != 'platform':
    for line, what in backend_branches(source):
      problems.append(
          f'{module}:{line}: branches on the MJX implementation ({what}); '
          'ask the `platform.backend.Backend` for the capability or '
          "operation instead (backend.of(data), the environment's backend)"
      )
  return problems


def package_violations(root: pathlib.Path = ROOT) -> list[str]:
  modules = package_modules(root)
  problems = []
  for module, path in modules.items():
    problems += violations(
        module, path.read_text(), modules, path.name == '__init__.py'
    )
  return problems


def test_the_package_keeps_the_layer_rule():
  problems = package_violations()
  assert not problems, 'Layer rule broken:\n' + '\n'.join(problems)


def test_every_layer_is_known():
  assert set(ALLOWED) == set(LAYER_OF.values())
  for layer, allowed in ALLOWED.items():
    assert allowed <= set(ALLOWED), layer


def test_a_planted_violation_is_reported(tmp_path):
  """A copy of the package with bad imports planted: each one is reported."""
  root = tmp_path / PACKAGE
  for path in ROOT.rglob('*.py'):
    copy = root / path.relative_to(ROOT)
    copy.parent.mkdir(parents=True, exist_ok=True)
    copy.write_text(path.read_text())
  assert not package_violations(root)
  (root / 'platform' / 'planted.py').write_text(
      'import jax\n'
      '\n'
      'from mjx_composer import environment\n'
      '\n'
      '\n'
      'def later(data):\n'
      '  from jax._src import core  # function-local: found too\n'
      '  from mjx_composer.runtime import transitions\n'
      '  return data._impl\n'
  )
  (root / 'entity_planted.py').write_text(
      'from mujoco.mjx._src import math\nfrom .suite import tasks\n'
  )
  problems = package_violations(root)
  print('\n'.join(problems))  # shown with pytest -s
  assert problems == [
      'mjx_composer.entity_planted: in no layer; add it to LAYER_OF in '
      'tests/package/test_layers.py and to the Layers table of ARCHITECTURE.md',
      'mjx_composer.platform.planted:3: platform imports '
      'mjx_composer.environment (environment); platform may import '
      "['platform']",
      'mjx_composer.platform.planted:7: imports the private module '
      f'jax._src.core; only {INTERNALS} may (add a named function there)',
      'mjx_composer.platform.planted:8: platform imports '
      'mjx_composer.runtime.transitions (runtime); platform may import '
      "['platform']",
      "mjx_composer.platform.planted:9: reads MJX's private `_impl`; only "
      f'{INTERNALS} may (internals.data_impl, internals.option_impl, ...)',
  ]
  # Classified as authoring, the relative import of suite/ is refused too.
  LAYER_OF['entity_planted'] = 'authoring'
  try:
    problems = package_violations(root)
  finally:
    del LAYER_OF['entity_planted']
  assert [p.split(': ', 1)[0] for p in problems if 'entity_planted' in p] == [
      'mjx_composer.entity_planted:1',
      'mjx_composer.entity_planted:2',
  ]
  assert 'authoring imports mjx_composer.suite.tasks (content)' in problems[1]


def test_a_planted_backend_branch_is_reported():
  """Each way of asking "is this Warp?" outside `platform/` is reported."""
  source = (
      'from mujoco import mjx\n'
      'from mjx_composer.platform import backend\n'
      '\n'
      '\n'
      'def f(model, data, impl, options):\n'
      '  if backend.is_warp(model):\n'
      '    return 1\n'
      "  if impl == 'warp' or options.impl != 'jax':\n"
      '    return 2\n'
      "  if impl in ('jax', 'warp'):\n"
      '    return 3\n'
      '  if data.impl == mjx.Impl.WARP:\n'
      '    return 4\n'
      '  # Asking the backend is fine.\n'
      '  if backend.of(data).staged_forward:\n'
      '    return 5\n'
      "  return impl == 'full'\n"
  )
  assert backend_branches(source) == [
      (6, 'calls is_warp'),
      (8, "compares with 'jax'/'warp'"),
      (10, "compares with 'jax'/'warp'"),
      (12, 'reads Impl.WARP'),
  ]
  modules = {'mjx_composer.runtime.planted': None}
  problems = violations('mjx_composer.runtime.planted', source, modules)
  assert [p.split(': ', 1)[0] for p in problems] == [
      'mjx_composer.runtime.planted:6',
      'mjx_composer.runtime.planted:8',
      'mjx_composer.runtime.planted:10',
      'mjx_composer.runtime.planted:12',
  ]
  assert all('branches on the MJX implementation' in p for p in problems)
  # platform/ is where the implementations are told apart.
  assert not violations('mjx_composer.platform.planted', source, modules)


def test_a_planted_frame_read_and_monkeypatch_are_reported():
  """Stack frames read and other packages' attributes assigned: reported."""
  source = (
      'import inspect\n'
      'import sys\n'
      '\n'
      'import numpy as np\n'
      'from brax.training.agents.ppo import train as ppo_train\n'
      'from mjx_composer.training import config\n'
      '\n'
      '\n'
      'def f(proxy, state):\n'
      '  frame = sys._getframe(1)\n'
      "  state = frame.f_locals['training_state']\n"
      '  caller = inspect.currentframe().f_back\n'
      '  ppo_train.optax = proxy\n'
      "  setattr(np.random, 'seed', proxy)\n"
      '  np.random.calls += 1\n'
      '  # Our own modules, and objects that are not modules: fine.\n'
      '  config.DEFAULT = 1\n'
      '  state.value = 2\n'
      "  setattr(state, 'name', caller)\n"
  )
  assert patches(source) == [
      (10, 'reads a stack frame (_getframe)'),
      (11, 'reads a stack frame (f_locals)'),
      (12, 'reads a stack frame (currentframe)'),
      (12, 'reads a stack frame (f_back)'),
      (13, "assigns an attribute of another package's ppo_train"),
      (14, "assigns an attribute of another package's np"),
      (15, "assigns an attribute of another package's np"),
  ]
  modules = {'mjx_composer.training.planted': None}
  problems = violations('mjx_composer.training.planted', source, modules)
  assert [p.split(': ', 1)[0] for p in problems] == [
      f'mjx_composer.training.planted:{line}'
      for line in (10, 11, 12, 12, 13, 14, 15)
  ]
  assert all('use the public API' in p for p in problems)
  # The internals modules are where other packages' internals are touched.
  assert not violations('mjx_composer.platform.internals_jax', source, modules)
