"""The host side of `compiler.set_const`: which statistics the compiler set.

`test_compiler.py` compares the device's `mj_setConst` quantities with
recompiled models; this checks `auto_stat`, which decides on the host which
statistics a spec set (and so must keep) and which the compiler computed.
"""

import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_composer.compiler import set_const

_HUMANOID = (
    pathlib.Path(set_const.__file__).parents[1]
    / 'suite'
    / 'entities'
    / 'assets'
    / 'humanoid'
    / 'humanoid.xml'
)

_SCENE = """
<mujoco>
  <asset>
    <hfield name="terrain" nrow="3" ncol="3" size="1 1 0.2 0.1"
            elevation="0 1 0 1 0 1 0 1 0"/>
  </asset>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <geom type="hfield" hfield="terrain" pos="3 0 0"/>
    <body pos="0 0 1">
      <joint type="free"/>
      <geom type="box" size="0.1 0.2 0.3"/>
      <site pos="0.5 0 0"/>
      <body pos="0.3 0 0">
        <joint type="hinge" axis="0 1 0" pos="-0.1 0 0"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.05"/>
        <body pos="0.4 0 0">
          <joint type="ball"/>
          <geom type="sphere" size="0.07"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _models():
  yield 'humanoid', mujoco.MjModel.from_xml_path(str(_HUMANOID))
  yield 'scene', mujoco.MjModel.from_xml_string(_SCENE)
  set_in_spec = _SCENE.replace(
      '<mujoco>', '<mujoco><statistic extent="7" center="1 2 3"/>'
  )
  yield 'scene with statistics', mujoco.MjModel.from_xml_string(set_in_spec)


def _compile_listener(compiles):
  def listener(event, duration, **kwargs):
    del duration, kwargs
    if event == '/jax/core/compile/backend_compile_duration':
      compiles.append(event)

  return listener


@pytest.mark.parametrize('name', ['humanoid', 'scene', 'scene with statistics'])
def test_auto_stat_tells_computed_from_set_statistics_without_compiling(name):
  """Computed statistics are recognised; spec-set ones are not; no XLA.

  The host recomputation runs in numpy: as eager JAX operations it compiled
  about fifty tiny programs while an environment's reset was traced.
  """
  m = dict(_models())[name]
  compiles = []
  jax.monitoring.register_event_duration_secs_listener(
      _compile_listener(compiles)
  )
  auto = set_const.auto_stat(m)
  assert not compiles
  # dm_control's humanoid sets <statistic extent="2" center="0 0 1"/>.
  spec_set = name in ('humanoid', 'scene with statistics')
  assert auto['extent'] is not spec_set
  assert auto['center'] is not spec_set
  for stat in ('meaninertia', 'meanmass', 'meansize'):
    assert auto[stat], stat


def test_geometry_stat_is_the_same_in_numpy_and_on_the_device():
  for name, m in _models():
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    host = set_const.geometry_stat(m, m, data, xp=np)
    device_model = type(
        'Model',
        (),
        dict(
            geom_rbound=jnp.asarray(m.geom_rbound, jnp.float32),
            geom_size=jnp.asarray(m.geom_size, jnp.float32),
            stat=type('Stat', (), dict(extent=jnp.float32(m.stat.extent))),
        ),
    )
    fields = ('xpos', 'xipos', 'xanchor', 'site_xpos', 'geom_xpos')
    device_data = type(
        'Data',
        (),
        {f: jnp.asarray(getattr(data, f), jnp.float32) for f in fields},
    )
    device = jax.jit(
        lambda: set_const.geometry_stat(m, device_model, device_data)
    )()
    for h, d in zip(host, device):
      np.testing.assert_allclose(h, d, rtol=1e-5, atol=1e-6, err_msg=name)


@pytest.mark.parametrize('n', [1, 3, 27])
def test_the_cpus_inverse_matches_numpy_and_calls_no_lapack(n):
  rng = np.random.default_rng(n)
  a = rng.normal(size=(4, n, n))
  a = a @ np.swapaxes(a, -1, -2) + n * np.eye(n)
  expected = np.linalg.inv(a)
  inverse = jax.jit(
      jax.vmap(
          lambda x: jax.lax.platform_dependent(
              x,
              cpu=set_const._spd_inverse_in_xla,
              default=set_const._spd_inverse,
          )
      )
  )
  a32 = jnp.asarray(a, jnp.float32)
  np.testing.assert_allclose(
      inverse(a32), expected, rtol=0, atol=2e-6 * np.abs(expected).max()
  )
  np.testing.assert_allclose(
      set_const._spd_inverse_in_xla(a32[0]),
      set_const._spd_inverse(a32[0]),
      rtol=0,
      atol=2e-6 * np.abs(expected).max(),
  )
  # Batched LAPACK calls can deadlock XLA's CPU thread pool when two run
  # at once: the CPU program has none.
  assert 'lapack' not in inverse.lower(a32).as_text()
