"""Compile-equivalence of MJCF variations (mjx_composer.compiler).

For every supported attribute, sampled worlds are compared field by field
(every leaf of the mjx.Model pytree, and its static metadata) with the model
MuJoCo compiles after setting the same values on the MjSpec, and a short
rollout of varied worlds is compared with rollouts of the recompiled models.

Tolerances: rtol=1e-5, atol=1e-6 (float32 on the device against the
compiler's float64, rounded to float32 by put_model), except where noted.
"""

import dataclasses
import inspect
import pathlib

import jax
import jax.extend as jex
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.compiler import attributes
from mjx_composer.compiler import inertia
from mjx_composer.compiler import planner
from tests import conftest

_J = mujoco.mjtJoint
_G = mujoco.mjtGeom
RTOL, ATOL = 1e-5, 1e-6
# Geoms that collide with the floor only: fewer collision kinds keep the
# rollout's compile time down (the floor has contype = conaffinity = 1).
_FLOOR_ONLY = dict(contype=2, conaffinity=1)


# -- the scene ----------------------------------------------------------------


class Arm(conftest.SpecEntity, composer.Robot):
  """Hinge, slide and ball joints; a geom in an MjsFrame; a fromto capsule;
  an explicit inertial; position (dampratio, kv) and motor actuators; a
  spatial tendon; a camera and a light. Angles in degrees (spec default)."""

  def _build(self):
    spec = self._new_spec('arm')
    base = spec.worldbody.add_body(name='base', pos=[0, 0, 0.1])
    self.shoulder = base.add_joint(
        name='shoulder',
        type=_J.mjJNT_HINGE,
        axis=[0, 1, 0],
        range=[-60, 60],
        damping=0.5,
        armature=0.01,
        frictionloss=0.05,
    )
    self.rod = base.add_geom(
        name='rod',
        type=_G.mjGEOM_CAPSULE,
        size=[0.03, 0, 0],
        fromto=[0, 0, 0, 0.3, 0, 0],
        contype=0,
        conaffinity=0,
    )
    self.box = base.add_geom(
        name='box',
        type=_G.mjGEOM_BOX,
        size=[0.05, 0.04, 0.03],
        pos=[0, 0, 0.05],
        quat=[0.9, 0.1, 0.2, 0.3],
        contype=0,
        conaffinity=0,
    )
    self.base_site = base.add_site(name='base_site', pos=[0.05, 0, 0.02])
    base.add_light(name='lamp', pos=[0, 0, 1], dir=[0, 0.3, -1])
    upper = base.add_body(
        name='upper', pos=[0.3, 0, 0], quat=[0.95, 0, 0.3, 0.1]
    )
    self.upper = upper
    self.slide = upper.add_joint(
        name='slide',
        type=_J.mjJNT_SLIDE,
        axis=[1, 0, 0],
        range=[-0.1, 0.1],
        stiffness=2.0,
        damping=0.2,
    )
    self.knob = upper.add_geom(
        name='knob',
        type=_G.mjGEOM_SPHERE,
        size=[0.04, 0, 0],
        density=500,
        contype=0,
        conaffinity=0,
    )
    frame = upper.add_frame(pos=[0.1, 0, 0.02], quat=[0.7, 0.7, 0, 0])
    self.cyl = frame.add_geom(
        name='cyl',
        type=_G.mjGEOM_CYLINDER,
        size=[0.02, 0.06, 0],
        pos=[0.02, 0, 0],
        mass=0.3,
        contype=0,
        conaffinity=0,
    )
    self.upper_site = upper.add_site(name='upper_site', pos=[0.1, 0.02, 0])
    upper.add_camera(name='cam', pos=[0.2, 0, 0.3])
    wrist = upper.add_body(name='wrist', pos=[0.2, 0, 0])
    self.wrist = wrist
    self.ball_joint = wrist.add_joint(
        name='wristball',
        type=_J.mjJNT_BALL,
        range=[0, 45],
        damping=0.1,
        armature=0.002,
    )
    wrist.mass = 0.4
    wrist.ipos = [0.01, 0.0, 0.02]
    wrist.inertia = [0.003, 0.0025, 0.002]
    wrist.iquat = [1, 0.2, 0, 0]
    wrist.explicitinertial = True
    self.ell = wrist.add_geom(
        name='ell',
        type=_G.mjGEOM_ELLIPSOID,
        size=[0.03, 0.02, 0.05],
        contype=0,
        conaffinity=0,
    )
    self.servo = spec.add_actuator(
        name='servo', target='shoulder', trntype=mujoco.mjtTrn.mjTRN_JOINT
    )
    self.servo.set_to_position(kp=20, dampratio=1.0)
    self.servo.ctrlrange = [-1, 1]
    self.motor = spec.add_actuator(
        name='motor',
        target='slide',
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        gear=[2, 0, 0, 0, 0, 0],
        ctrlrange=[-1, 1],
        forcerange=[-5, 5],
    )
    self.site_servo = spec.add_actuator(
        name='site_servo',
        target='upper_site',
        trntype=mujoco.mjtTrn.mjTRN_SITE,
        gear=[0, 0, 1, 0, 0, 0],
    )
    self.site_servo.set_to_position(kp=3, kv=0.2)
    tendon = spec.add_tendon(
        name='tendon', stiffness=1.0, springlength=[-1, -1]
    )
    tendon.wrap_site('base_site')
    tendon.wrap_site('upper_site')

  @property
  def actuators(self):
    return (self.servo, self.motor, self.site_servo)


class Prop(conftest.SpecEntity):
  """Two geoms in one body: the inertial frame comes from an eigen-solve."""

  def _build(self):
    spec = self._new_spec('prop')
    body = spec.worldbody.add_body(name='body')
    self.body = body
    self.sphere = body.add_geom(
        name='sphere',
        type=_G.mjGEOM_SPHERE,
        size=[0.05, 0, 0],
        mass=0.2,
        **_FLOOR_ONLY,
    )
    self.cube = body.add_geom(
        name='cube',
        type=_G.mjGEOM_BOX,
        size=[0.03, 0.03, 0.03],
        pos=[0.06, 0.01, 0],
        density=800,
        **_FLOOR_ONLY,
    )


class Slider(conftest.SpecEntity):
  """A slide-only "simple" body (MuJoCo's body_simple == 2) over a rail
  geom that sits in the entity's worldbody."""

  def _build(self):
    spec = self._new_spec('slider')
    # In the entity's worldbody: compiled into its attachment frame body.
    self.rail = spec.worldbody.add_geom(
        name='rail',
        type=_G.mjGEOM_BOX,
        size=[0.5, 0.02, 0.01],
        pos=[0, 0.5, 0.15],
        **_FLOOR_ONLY,
    )
    body = spec.worldbody.add_body(name='carriage', pos=[0, 0.5, 0.2])
    body.add_joint(name='x', type=_J.mjJNT_SLIDE, axis=[1, 0, 0])
    self.body = body
    self.puck = body.add_geom(
        name='puck', type=_G.mjGEOM_BOX, size=[0.05, 0.05, 0.02], **_FLOOR_ONLY
    )


class SceneTask(composer.Task):
  """Arena (radians, fluid), arm under a rotated site, a free prop, a slider,
  cameras (one tracking the prop) and inactive connect/weld equalities."""

  def __init__(self):
    self.arena = arena = composer.Arena()
    spec = arena.mjcf_model
    spec.option.density = 1.2
    spec.option.viscosity = 2e-5
    spec.option.wind = [0.1, 0, 0]
    world = spec.worldbody
    self.floor = world.add_geom(
        name='floor', type=_G.mjGEOM_PLANE, size=[2, 2, 0.1]
    )
    world.add_camera(name='overview', pos=[0, -2, 1], quat=[0.8, 0.6, 0, 0])
    world.add_camera(
        name='tracker',
        pos=[1, 0, 1],
        mode=mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODYCOM,
        targetbody='prop/body',
    )
    mount = world.add_site(
        name='mount', pos=[0.1, -0.2, 0.3], quat=[0.9, 0, 0, 0.43]
    )
    self.arm = Arm()
    arena.attach(self.arm, mount)
    self.prop = Prop()
    arena.add_free_entity(self.prop)
    self.prop.attachment_frame.pos = [0.5, 0.3, 0.2]
    self.slider = Slider()
    arena.attach(self.slider)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_CONNECT,
        name1='arm/wrist',
        name2='prop/body',
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        data=[0.01, 0, 0] + [0] * 9,
        active=False,
    )
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_WELD,
        name1='arm/upper',
        name2='slider/carriage',
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        active=False,
    )

  @property
  def root_entity(self):
    return self.arena

  def get_reward(self, physics):
    return 0.0


def _groups(task):
  """Bindings per attribute group: {group: [(element, attr), ...]}."""
  arm, prop, slider = task.arm, task.prop, task.slider
  option = task.arena.mjcf_model.option
  return {
      'geom_size': [
          (arm.box, 'size'),
          (arm.rod, 'size'),
          (arm.cyl, 'size'),
          (arm.knob, 'size'),
          (arm.ell, 'size'),
          (prop.sphere, 'size'),
          (slider.puck, 'size'),
          (slider.rail, 'size'),
          (task.floor, 'size'),
      ],
      'geom_mass': [
          (arm.cyl, 'mass'),
          (arm.knob, 'density'),
          (prop.cube, 'density'),
          (prop.sphere, 'mass'),
      ],
      'geom_pose': [
          (prop.cube, 'pos'),
          (prop.cube, 'quat'),
          (arm.box, 'pos'),
          (arm.box, 'quat'),
          (slider.rail, 'pos'),
      ],
      'geom_contact': [
          (prop.sphere, 'rgba'),
          (prop.sphere, 'friction'),
          (prop.sphere, 'solref'),
          (prop.sphere, 'solimp'),
          (arm.box, 'rgba'),
      ],
      'body_inertial': [
          (arm.wrist, 'mass'),
          (arm.wrist, 'inertia'),
          (arm.wrist, 'ipos'),
          (arm.wrist, 'iquat'),
      ],
      'body_pose': [
          (arm.upper, 'pos'),
          (arm.upper, 'quat'),
          (prop.attachment_frame, 'pos'),
          (prop.attachment_frame, 'quat'),
          (slider.attachment_frame, 'pos'),
          (slider.attachment_frame, 'quat'),
      ],
      'site_pose': [
          (arm.upper_site, 'pos'),
          (arm.upper_site, 'quat'),
          (arm.base_site, 'pos'),
      ],
      'joint': [
          (arm.shoulder, 'damping'),
          (arm.slide, 'stiffness'),
          (arm.shoulder, 'armature'),
          (arm.ball_joint, 'armature'),
          (arm.shoulder, 'frictionloss'),
          (arm.shoulder, 'range'),
          (arm.ball_joint, 'range'),
          (arm.slide, 'range'),
      ],
      'actuator': [
          (arm.motor, 'gear'),
          (arm.site_servo, 'gear'),
          (arm.motor, 'ctrlrange'),
          (arm.motor, 'forcerange'),
          (arm.servo, 'kp'),
          (arm.site_servo, 'kv'),
      ],
      'option': [
          (option, 'gravity'),
          (option, 'wind'),
          (option, 'density'),
          (option, 'viscosity'),
      ],
  }


def _perturb(rng, value, attr, scale=1.0):
  """A random valid value near `value` (float64)."""
  value = np.array(value, np.float64)
  if attr in ('quat', 'iquat'):
    return value + scale * rng.uniform(-0.4, 0.4, value.shape)
  if attr in ('pos', 'ipos'):
    return value + scale * rng.uniform(-0.05, 0.05, value.shape)
  if attr in ('range', 'ctrlrange', 'forcerange'):
    return value * (1 + scale * rng.uniform(-0.3, 0.3))
  if attr in ('gravity', 'wind'):
    return value + scale * rng.uniform(-1, 1, value.shape)
  if attr == 'inertia':  # keep the triangle inequality
    return value * (1 + scale * rng.uniform(-0.1, 0.1, value.shape))
  if attr == 'rgba':
    return rng.uniform(0, 1, value.shape)
  return value * (1 + scale * rng.uniform(-0.3, 0.3, value.shape))


@pytest.fixture(scope='module')
def scene():
  """Compiles the scene once, and the device compiler for all groups."""
  task = SceneTask()
  env = composer.Environment(task)
  groups = _groups(task)
  bindings = [(e, a, g) for g, items in groups.items() for e, a in items]
  compiler = planner.ModelCompiler(
      env.initial_physics().index,
      [(e, a, f'{g}:{a}') for e, a, g in bindings],
  )
  defaults = [
      attributes.spec_value(e, attributes.kind_of(e), a) for e, a, _ in bindings
  ]
  rng = np.random.RandomState(0)
  worlds = {'defaults': list(defaults)}
  for group in groups:
    worlds[group] = [
        _perturb(rng, v, a) if g == group else v
        for v, (_, a, g) in zip(defaults, bindings)
    ]
  worlds['all'] = [
      _perturb(rng, v, a) for v, (_, a, _) in zip(defaults, bindings)
  ]
  names = list(worlds)
  values = [
      jnp.asarray(np.stack([worlds[n][i] for n in names]), jnp.float32)
      for i in range(len(bindings))
  ]
  fields = jax.jit(jax.vmap(compiler, in_axes=(None, 0)))(env.mjx_model, values)
  return dict(
      task=task,
      env=env,
      bindings=bindings,
      worlds=worlds,
      names=names,
      fields=fields,
      compiler=compiler,
  )


def _world_model(scene, w):
  """The varied mjx.Model of world number `w`."""
  fields = jax.tree.map(lambda x: x[w], scene['fields'])
  return scene['env'].mjx_model.replace(**fields)


def _recompiled(scene, values):
  """mjx.put_model of the spec recompiled with `values` set (then restored)."""
  task, bindings = scene['task'], scene['bindings']
  saved = [
      attributes.spec_value(e, attributes.kind_of(e), a) for e, a, _ in bindings
  ]
  try:
    for (e, a, _), v in zip(bindings, values):
      attributes.set_spec_value(e, attributes.kind_of(e), a, v)
    spec, _ = task.root_entity.compose()
    return mjx.put_model(spec.compile())
  finally:
    for (e, a, _), v in zip(bindings, saved):
      attributes.set_spec_value(e, attributes.kind_of(e), a, v)


# Static metadata that MJX never reads (checked below against its source),
# so a varied world may keep the compiled values: MuJoCo's frame flags.
_UNUSED_STATIC = ('body_sameframe', 'geom_sameframe', 'site_sameframe')


def _leaves(tree):
  flat, _ = jax.tree_util.tree_flatten_with_path(tree)
  return {jax.tree_util.keystr(p): np.asarray(v) for p, v in flat}


def _statics(obj, prefix=''):
  out = {}
  for f in dataclasses.fields(obj):
    value = getattr(obj, f.name)
    if isinstance(value, np.ndarray):
      out[prefix + f.name] = value
    elif dataclasses.is_dataclass(value):
      out.update(_statics(value, prefix + f.name + '.'))
  return out


def _quat_close(a, b, rtol=RTOL, atol=ATOL):
  """q and -q are the same rotation."""
  return np.allclose(a, b, rtol=rtol, atol=atol) or np.allclose(
      a, -b, rtol=rtol, atol=atol
  )


def _check_body_iquat(varied, reference):
  """Principal axes: compare the inertia tensors R diag(I) R^T.

  When principal moments are (nearly) equal the eigenbasis is not unique,
  and its float32 error grows as 1/gap; the tensor is what physics uses.
  Well separated moments must give the same quaternion (up to sign).
  """
  for b in range(varied.nbody):
    q1 = np.asarray(varied.body_iquat[b])
    q2 = np.asarray(reference.body_iquat[b])
    i1 = np.asarray(varied.body_inertia[b])
    i2 = np.asarray(reference.body_inertia[b])
    r1, r2 = np.zeros(9), np.zeros(9)
    mujoco.mju_quat2Mat(r1, q1.astype(np.float64))
    mujoco.mju_quat2Mat(r2, q2.astype(np.float64))
    t1 = r1.reshape(3, 3) @ np.diag(i1) @ r1.reshape(3, 3).T
    t2 = r2.reshape(3, 3) @ np.diag(i2) @ r2.reshape(3, 3).T
    scale = max(np.max(np.abs(i2)), 1e-30)
    np.testing.assert_allclose(
        t1, t2, rtol=0, atol=2e-6 * scale, err_msg=f'inertia tensor of body {b}'
    )
    gap = np.min(np.abs(np.diff(np.sort(i2)))) / scale
    if gap > 1e-2:
      assert _quat_close(q1, q2), (b, q1, q2)


def _compare(varied, reference, label):
  bad = []
  a, b = _leaves(varied), _leaves(reference)
  assert a.keys() == b.keys()
  for key in a:
    if key in ('.body_iquat',):
      continue
    x, y = a[key], b[key]
    assert x.shape == y.shape, (label, key, x.shape, y.shape)
    if key in ('.body_quat', '.geom_quat', '.site_quat', '.cam_quat'):
      ok = all(_quat_close(p, q) for p, q in zip(x, y))
    else:
      ok = np.allclose(x, y, rtol=RTOL, atol=ATOL, equal_nan=True)
    if not ok:
      diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
      i = np.unravel_index(np.nanargmax(diff), diff.shape)
      bad.append(f'{key}{list(i)}: {x[i]} vs {y[i]}')
  _check_body_iquat(varied, reference)
  sa, sb = _statics(varied), _statics(reference)
  assert sa.keys() == sb.keys()
  hfield = np.asarray(varied.geom_type) == mujoco.mjtGeom.mjGEOM_HFIELD
  for key in sa:
    if key in _UNUSED_STATIC:
      continue
    x, y = sa[key], sb[key]
    if key == '_impl.geom_rbound_hfield':
      # put_model's copy of geom_rbound, read only for height fields (whose
      # size cannot vary).
      x, y = x[hfield], y[hfield]
    if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
      bad.append(f'static {key}: {x.ravel()[:6]} vs {y.ravel()[:6]}')
  assert not bad, f'{label}: ' + '; '.join(bad)


def test_unused_static_fields_are_not_read_by_mjx():
  """Guards the exclusions above: MJX's source never reads these flags."""
  source_dir = pathlib.Path(inspect.getfile(mjx)).parent / '_src'
  sources = [
      p.read_text()
      for p in source_dir.glob('*.py')
      if not p.name.endswith('_test.py') and p.name != 'types.py'
  ]
  for name in _UNUSED_STATIC:
    assert not any(name in s for s in sources), name
  # geom_rbound_hfield is read by the height-field collision only.
  readers = [
      p.name
      for p in source_dir.glob('*.py')
      if not p.name.endswith('_test.py')
      and p.name not in ('types.py', 'io.py')
      and 'geom_rbound_hfield' in p.read_text()
  ]
  assert readers == ['collision_driver.py'], readers


def test_refusals_that_depend_on_the_composed_model():
  task = SceneTask()
  env = composer.Environment(task)
  index = env.initial_physics().index

  def build(element, attr):
    attributes.check_attribute(element, attr)
    return planner.ModelCompiler(index, [(element, attr, attr)])

  # The slider's frame body gets the entity's worldbody geom (the rail):
  # its handle has no geoms, but the compiled body infers its inertia.
  with pytest.raises(ValueError, match='infers its mass and inertia'):
    build(task.slider.attachment_frame, 'mass')
  # The carriage is a simple body: its single geom must stay centred.
  with pytest.raises(ValueError, match='simple'):
    build(task.slider.puck, 'quat')
  # Fine: sizes keep a single geom's frame.
  build(task.slider.puck, 'size')


def _check_output_fields(scene, references):
  """Only fields the bound attributes can affect are replaced (per world)."""
  fields = set(scene['fields'])
  base = _leaves(scene['env'].mjx_model)
  changed = set()
  for reference in references.values():
    varied = _leaves(reference)
    changed |= {
        k.split('.')[1].split('[')[0]
        for k in base
        if not np.allclose(base[k], varied[k], rtol=RTOL, atol=ATOL)
    }
  assert changed <= fields, changed - fields
  # Nothing unrelated (e.g. sensor or asset fields) is carried.
  assert not {
      f
      for f in fields
      if f.startswith(('sensor_', 'mesh_', 'tex_', 'key_', 'hfield_'))
  }


def _check_rollouts(scene, references, worlds=('defaults', 'body_pose', 'all')):
  """50 steps under constant controls, varied vs recompiled."""
  varied = [_world_model(scene, scene['names'].index(w)) for w in worlds]
  treedef = jax.tree.structure(varied[0])
  # The recompiled models differ only in static flags MJX never reads (see
  # above); give them the varied models' metadata so one compiled rollout
  # runs both.
  reference = [
      jax.tree.unflatten(treedef, jax.tree.leaves(references[w]))
      for w in worlds
  ]
  models = jax.tree.map(lambda *x: jnp.stack(x), *(varied + reference))
  ctrl = jnp.asarray([0.4, -0.6, 0.3], jnp.float32)

  @jax.jit
  @jax.vmap
  def rollout(model):
    data = mjx.make_data(model).replace(ctrl=ctrl)

    def step(data, _):
      data = mjx.step(model, data)
      return data, jnp.concatenate([data.qpos, data.qvel])

    _, states = jax.lax.scan(step, data, None, length=50)
    return states

  states = np.asarray(rollout(models))
  n = len(worlds)
  for i, world in enumerate(worlds):
    # Trajectories of float32 models that agree to ~1e-6 drift apart
    # slowly; contacts and the solver amplify it.
    np.testing.assert_allclose(
        states[i], states[n + i], rtol=0, atol=1e-3, err_msg=world
    )
  # The varied worlds really differ from the default one.
  assert np.max(np.abs(states[n - 1] - states[0])) > 1e-2


def test_sampled_worlds_equal_recompiled_models(scene):
  """Per attribute group (and all at once): every field, then rollouts.

  One test, so that the scene is compiled once even when pytest-xdist
  spreads tests over workers.
  """
  references = {
      world: _recompiled(scene, values)
      for world, values in scene['worlds'].items()
  }
  failures = []
  for w, world in enumerate(scene['names']):
    try:
      _compare(_world_model(scene, w), references[world], world)
    except AssertionError as e:
      failures.append(str(e))
  assert not failures, '\n'.join(failures)
  _check_output_fields(scene, references)
  _check_rollouts(scene, references)


def test_eig3_matches_mujoco_principal_axes():
  """Principal moments and axes against the compiler's (fullinertia)."""
  rng = np.random.RandomState(1)
  matrices, refs = [], []
  for _ in range(40):
    quat = rng.randn(4)
    quat /= np.linalg.norm(quat)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, quat)
    rot = rot.reshape(3, 3)
    moments = rng.uniform(0.5, 1.0, 3) * 10 ** rng.uniform(-5, 0)
    full = rot @ np.diag(moments) @ rot.T
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(mass=1, ipos=[0, 0, 0])
    body.add_freejoint()
    body.fullinertia = [
        full[0, 0],
        full[1, 1],
        full[2, 2],
        full[0, 1],
        full[0, 2],
        full[1, 2],
    ]
    m = spec.compile()
    matrices.append(full)
    refs.append((m.body_inertia[1].copy(), m.body_iquat[1].copy()))
  values, quats = jax.jit(jax.vmap(inertia.eig3))(
      jnp.asarray(np.stack(matrices), jnp.float32)
  )
  for (ref_i, ref_q), i, q, full in zip(
      refs, np.asarray(values), np.asarray(quats), matrices
  ):
    scale = np.max(ref_i)
    np.testing.assert_allclose(i, ref_i, rtol=0, atol=1e-6 * scale)
    gap = np.min(np.abs(np.diff(np.sort(ref_i)))) / scale
    # Eigenvectors of a float32 matrix are good to ~eps32/gap (their
    # condition number), whatever the algorithm.
    tol = max(1e-6, 1.2e-7 / gap)
    assert _quat_close(q, ref_q, rtol=0, atol=tol), (q, ref_q, gap)


def test_eig3_degenerate_moments_give_the_same_tensor():
  """Equal moments: any eigenbasis is right; the tensor must match."""
  full = np.diag([2e-3, 2e-3, 1e-3])
  values, quat = jax.jit(inertia.eig3)(jnp.asarray(full, jnp.float32))
  rot = np.zeros(9)
  mujoco.mju_quat2Mat(rot, np.asarray(quat, np.float64))
  rot = rot.reshape(3, 3)
  np.testing.assert_allclose(
      rot @ np.diag(np.asarray(values)) @ rot.T, full, atol=1e-9
  )
  np.testing.assert_allclose(values, [2e-3, 2e-3, 1e-3], rtol=1e-6)


def test_statistics_set_in_the_spec_are_kept():
  """The compiler keeps `statistic` values the spec sets; so do we."""
  arena = composer.Arena()
  arena.mjcf_model.stat.meanmass = 3.0
  arena.mjcf_model.stat.extent = 5.0
  prop = Prop()
  arena.add_free_entity(prop)
  env = composer.Environment(composer.NullTask(arena))
  compiler = planner.ModelCompiler(
      env.initial_physics().index, [(prop.sphere, 'size', 'size')]
  )  # pylint: disable=protected-access
  fields = jax.jit(compiler)(env.mjx_model, [jnp.asarray([0.08, 0, 0])])
  saved = np.array(prop.sphere.size)
  try:
    prop.sphere.size = [0.08, 0, 0]
    spec, _ = arena.compose()
    reference = spec.compile()
  finally:
    prop.sphere.size = saved
  assert reference.stat.meanmass == 3.0 and reference.stat.extent == 5.0
  for name in ('meaninertia', 'meanmass', 'meansize', 'extent', 'center'):
    np.testing.assert_allclose(
        getattr(fields['stat'], name),
        getattr(reference.stat, name),
        rtol=RTOL,
        atol=ATOL,
        err_msg=name,
    )
  np.testing.assert_allclose(
      fields['body_inertia'], reference.body_inertia, rtol=RTOL, atol=ATOL
  )


def _loops(jaxpr) -> int:
  """The loops (`while`, `scan`) a GPU runs in a jaxpr, nested ones included.

  Of a `lax.platform_dependent` choice, only the branch for the GPU counts
  (`set_const` inverts the mass matrix with loops on the CPU only).
  """
  count = 0
  for eqn in jaxpr.eqns:
    count += eqn.primitive.name in ('while', 'scan')
    subs = jex.core.jaxprs_in_params(eqn.params)
    platforms = eqn.params.get('branches_platforms')
    if platforms is not None:
      subs = [
          branch.jaxpr
          for branch, names in zip(eqn.params['branches'], platforms)
          if names is None or 'cuda' in names
      ]
    for sub in subs:
      count += _loops(sub)
  return count


def test_principal_axes_of_several_bodies_come_from_one_loop():
  """`bodies_inertial` runs one Jacobi loop for all bodies, none for one geom.

  On a GPU every iteration of a loop is a kernel launch per loop: a loop per
  body made the walk task's randomized reset twice as slow. Two props of two
  geoms each need principal axes (one loop); a body of one geom copies the
  geom's frame (no loop). Beside it, `set_const` forms the bodies'
  translational inverse weights in one loop over the bodies (a few small
  kernels an iteration, where every body at once held the randomized
  restart's largest temporaries).
  """

  class Ball(conftest.SpecEntity):

    def _build(self):
      body = self._new_spec('ball').worldbody.add_body(name='body')
      self.sphere = body.add_geom(
          type=_G.mjGEOM_SPHERE, size=[0.05, 0, 0], **_FLOOR_ONLY
      )

  arena = composer.Arena()
  props, balls = [Prop(), Prop()], [Ball(), Ball()]
  for i, entity in enumerate(props + balls):
    entity.mjcf_model.modelname += str(i)
    arena.add_free_entity(entity)
  env = composer.Environment(composer.NullTask(arena))
  index = env.initial_physics().index

  def loops(bindings):
    compiler = planner.ModelCompiler(index, bindings)
    values = [jnp.asarray(v) for v in compiler.initial_values]
    return _loops(jax.make_jaxpr(compiler)(env.mjx_model, values).jaxpr)

  assert loops([(props[0].cube, 'density', 'density')]) == 2
  assert loops([(p.cube, 'density', 'density') for p in props]) == 2
  assert loops([(b.sphere, 'density', 'density') for b in balls]) == 1
  assert loops([(b.sphere, 'rgba', 'rgba') for b in balls]) == 0
