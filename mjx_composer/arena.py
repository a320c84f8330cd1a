"""`Arena`: the root entity of a scene, with composer's global defaults."""

import mujoco

from mjx_composer import entity


class Arena(entity.Entity):
  """The root of a scene, carrying composer's `arena.xml` defaults.

  The defaults are those of composer's arena where MJX honours them:
  `compiler boundmass=1e-5 boundinertia=1e-11` (so empty attachment frames
  with freejoints compile), radian angles, `option timestep=0.002` and
  elliptic friction cones, and the same headlight and visual scale. Composer's
  `noslip_iterations=5` is left out: MJX has no noslip solver, and asking for
  it would make MuJoCo on the host (our reference) disagree with MJX.

  Args:
    name: the arena's name (its spec's `modelname`).
    xml_path: optional MJCF file to start from instead of an empty scene.
  """

  def _build(self, name=None, xml_path=None):
    if xml_path is not None:
      spec = mujoco.MjSpec.from_file(str(xml_path))
    else:
      spec = mujoco.MjSpec()
      spec.compiler.degree = False
      spec.option.timestep = 0.002
      spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.compiler.boundmass = 1e-5
    spec.compiler.boundinertia = 1e-11
    spec.visual.map.znear = 0.01
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    spec.visual.headlight.ambient = [0.3, 0.3, 0.3]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.modelname = name or spec.modelname or 'arena'
    if spec.modelname == 'MuJoCo Model':
      spec.modelname = 'arena'
    self._spec = spec

  @property
  def mjcf_model(self):
    return self._spec

  def add_free_entity(self, entity_to_add):
    """Attaches an entity with a freejoint on its frame; returns the frame."""
    frame = self.attach(entity_to_add)
    frame.add_freejoint()
    return frame

  @property
  def ground_geoms(self):
    """Geoms that form the ground (none for a bare arena)."""
    return ()

  def regenerate(self, random_state):
    """Regenerates the arena's layout at build time (no-op by default).

    Composer's hook: it edits the spec on the host, before the one compile.
    """
    del random_state

  def regenerate_world(self, physics, key):
    """Samples one world's layout on the device (identity by default).

    The per-world counterpart of `regenerate`: write the model fields a
    regenerated spec would have compiled to, and return the physics. Call it
    from `initialize_episode`.
    """
    del key
    return physics
