"""Arena layouts regenerated per episode, from models compiled at build.

Composer regenerates an arena (`Arena.regenerate(random_state)`: a corridor's
width and walls, a maze's layout) and recompiles at every episode. On MJX the
model's structure is compiled once, but where regenerating only moves or
resizes existing elements (positions, sizes, colours, masses: the same bodies,
geoms and joints, in the same order), each regeneration compiles to the same
structure with different values. `EpisodeLayouts` compiles a number of
regenerations on the host when the environment is built, keeps the model
fields that differ between them, and writes one layout's values into a world's
model at each episode: exactly the fields MuJoCo's compiler gave that layout
(derived ones such as `geom_rbound` and `geom_aabb` included).

A regeneration that changes the structure (adds or removes geoms, changes a
geom's type, or changes any integer field) cannot be carried: `sample` raises
and names the first field that differs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer.model import element_index


class EpisodeLayouts:
  """Layouts compiled at build; `apply` writes a random one per episode.

  Args:
    count: how many regenerations to compile (at least 2).
  """

  def __init__(self, count: int):
    if isinstance(count, bool) or int(count) != count or count < 2:
      raise ValueError(
          f'The number of layouts must be an integer >= 2, got {count!r}: '
          'one layout is the compiled model itself.'
      )
    self.count = int(count)
    self.tables: dict[str, np.ndarray] | None = None

  def sample(self, root, regenerate, random_state) -> None:
    """Compiles `count` regenerations of `root`'s tree and keeps the tables.

    Args:
      root: the root entity; its `compose()` builds the whole tree.
      regenerate: the arena's `regenerate(random_state)`.
      random_state: the `numpy.random.RandomState` of the build.

    Raises:
      ValueError: the regenerations differ in structure.
    """
    models = []
    for _ in range(self.count):
      regenerate(random_state)
      spec, _ = root.compose()
      models.append(spec.compile())
    self.tables = layout_tables(models)

  def apply(self, physics, key):
    """Writes a uniformly drawn layout's fields into the world's model."""
    if not self.tables:
      return physics
    choice = jax.random.randint(key, (), 0, self.count)
    model = physics.model
    values = {}
    for field, table in self.tables.items():
      current = getattr(model, field)
      # MJX may lay a field out differently (geom_aabb is (ngeom, 2, 3)).
      layout = jnp.asarray(table, current.dtype)[choice]
      values[field] = layout.reshape(current.shape)
    return physics.replace(model=model.replace(**values))


def layout_tables(models: list[mujoco.MjModel]) -> dict[str, np.ndarray]:
  """`{field: values stacked over models}` for the MJX model fields that
  differ between models of one structure.

  Raises:
    ValueError: a size or an integer field differs: the structure changed.
  """
  first = models[0]
  tables = {}
  for field in sorted(element_index.MODEL_FIELDS):
    if field.startswith('_') or not hasattr(first, field):
      continue
    values = [getattr(m, field) for m in models]
    if not isinstance(values[0], np.ndarray):
      continue
    shapes = {v.shape for v in values}
    if len(shapes) > 1:
      raise ValueError(
          f'Regenerating the arena changed the model structure ({field} '
          f'has shapes {sorted(shapes)}): only positions, sizes and other '
          'values of existing elements can vary per episode on MJX.'
      )
    if all(np.array_equal(values[0], v) for v in values[1:]):
      continue
    if not np.issubdtype(values[0].dtype, np.floating):
      raise ValueError(
          f'Regenerating the arena changed {field}, an integer field of '
          'the model structure: only positions, sizes and other values of '
          'existing elements can vary per episode on MJX.'
      )
    tables[field] = np.stack(values)
  return tables
