"""Arenas: the root entities of bundled scenes."""

import mujoco

from mjx_composer import arena


class Floor(arena.Arena):
  """A flat, checkered floor with a light: composer's arena plus a ground.

  Args:
    size: (half-x, half-y) extent of the floor plane in metres.
    name: the arena's name.
  """

  def _build(self, size=(2., 2.), name='floor'):
    super()._build(name=name)
    spec = self.mjcf_model
    texture = spec.add_texture(
        name='grid', type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=256, height=256,
        rgb1=[.2, .3, .4], rgb2=[.1, .2, .3])
    spec.add_material(name='grid', texrepeat=[4, 4],
                      textures=['', 'grid'] + [''] * 8, reflectance=0.2)
    del texture
    self._ground = spec.worldbody.add_geom(
        name='ground', type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[size[0], size[1], 0.25], material='grid')
    spec.worldbody.add_light(name='top', pos=[0, 0, 4], dir=[0, 0, -1],
                             type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    spec.worldbody.add_camera(name='overview', pos=[1.6, -1.6, 1.4],
                              xyaxes=[1, 1, 0, -0.4, 0.4, 1])

  @property
  def ground_geoms(self):
    return (self._ground,)
