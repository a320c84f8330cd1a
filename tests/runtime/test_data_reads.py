"""What a traced function reads of an `mjx.Data` (`data_reads`)."""

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

from mjx_composer.runtime import data_reads

# Four 3-element sensors: 12 `sensordata` elements.
_XML = """
<mujoco>
  <worldbody>
    <body name="a">
      <joint name="hinge" axis="0 1 0"/>
      <geom type="capsule" size="0.05" fromto="0 0 0 0.3 0 0" mass="1"/>
      <site name="s" pos="0.3 0 0"/>
    </body>
  </worldbody>
  <sensor>
    <framepos objtype="site" objname="s"/>
    <velocimeter site="s"/>
    <gyro site="s"/>
    <accelerometer site="s"/>
  </sensor>
</mujoco>
"""


@pytest.fixture(scope='module')
def model():
  return mjx.put_model(mujoco.MjModel.from_xml_string(_XML))


def test_sensordata_read_takes_static_slices(model):
  data = mjx.make_data(model)

  def sliced(d):
    inner = jax.jit(lambda x: x[3:6] * 2.0)
    return (inner(d.sensordata), d.sensordata[9]), ()

  assert data_reads.reads(sliced, data).sensordata == {3, 4, 5, 9}

  def gathered(d):  # A binding of non-contiguous sensors takes an array.
    return d.sensordata[np.array([2, 7, 8, -1])], ()

  last = int(data.sensordata.shape[0]) - 1
  assert data_reads.reads(gathered, data).sensordata == {2, 7, 8, last}
  assert data_reads.reads(lambda d: (d.xpos, ()), data).sensordata == set()
  # A whole-array operation, or an index not known at trace time: all.
  assert (
      data_reads.reads(lambda d: (d.sensordata.sum(), ()), data).sensordata
      is None
  )

  def indexed(d, i):
    return d.sensordata[i], ()

  assert data_reads.reads(indexed, data, 2).sensordata is None

  def gathered_at(d, i):
    return d.sensordata[jnp.stack([i, i + 1])], ()

  assert data_reads.reads(gathered_at, data, 2).sensordata is None


def test_fields_read_follow_dependences(model):
  data = mjx.make_data(model)

  def fn(data, scale):
    branch = jax.lax.cond(
        scale > 0, lambda: data.cvel, lambda: jnp.zeros_like(data.cvel)
    )
    read = (data.xpos * scale, branch)
    ignored = (data.qacc, data.sensordata)
    return read, ignored

  assert data_reads.reads(fn, data, 1.0).fields == {'xpos', 'cvel'}


def test_depends_on_inputs_follows_the_selected_outputs():
  def fn(key, x):
    drawn = jax.random.uniform(key, (2,))
    return {'drawn': drawn, 'fixed': jnp.ones(3), 'moved': x + 1.0}

  closed, out = jax.make_jaxpr(fn, return_shape=True)(
      jax.random.key(0), jnp.zeros(2)
  )
  assert not data_reads.depends_on_inputs(closed, out, out['fixed'])
  assert data_reads.depends_on_inputs(closed, out, out['drawn'])
  assert data_reads.depends_on_inputs(closed, out, out['moved'])
  # A branch passes on the dependence of its operands.
  closed, out = jax.make_jaxpr(
      lambda x: jax.lax.cond(x > 0, lambda: 1.0, lambda: 2.0), return_shape=True
  )(1.0)
  assert data_reads.depends_on_inputs(closed, out, out)
