"""Tests for `fused_restart`: the auto-reset fused into the sub-step loop.

With `share_reset_forward`, `Environment.step` runs
`Transitions.step_and_restart` (same-step auto-reset) or
`Transitions.reset_or_step` (next-step), whose reset shares the sub-steps'
forward pass. These tests hold both to the composition they replace (`step`,
and `restart` where the episode ended or `reset` where the state is LAST,
selected per world) and the masked forward pass to MuJoCo's forward pass
with actuation disabled.
"""

import jax
import jax.extend
import jax.numpy as jnp
import mujoco
from mujoco import mjx
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer.runtime import control_flow
from mjx_composer.runtime import fused_restart
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.runtime import substep_sensors
from mjx_composer.variation import distributions
from mjx_composer.variation import mjcf_variator
from tests import conftest
from tests import jaxprs
from tests import test_environment


class _RandomizedSwing(conftest.SwingTask):
  """The swing task with the ball's size and mass drawn per episode, so
  that restarts write per-world model fields; it ends when the tip rises
  above 0.6, so that worlds restart at different steps."""

  def __init__(self):
    super().__init__(terminate_above=0.6)
    self.variator = mjcf_variator.MJCFVariator()
    self.variator.bind_attributes(
        self.ball.geom, size=distributions.Uniform([0.03, 0, 0], [0.08, 0, 0])
    )

  def initialize_episode(self, physics, key):
    variation_key, key = jax.random.split(key)
    physics = self.variator.apply_variations(physics, variation_key)
    return super().initialize_episode(physics, key)


def _swing(task=None, **options):
  """A swing `Environment` (`_RandomizedSwing` unless `task`) of 0.05 s
  episodes with these `ExecutionOptions`."""
  return composer.Environment(
      task or _RandomizedSwing(),
      time_limit=0.05,
      options=composer.ExecutionOptions(**options),
  )


@pytest.fixture(scope='module', params=['same_step', 'next_step'])
def env(request):
  return _swing(auto_reset=request.param)


@pytest.fixture(scope='module')
def reset_states(env):
  """Three worlds' first states, for the batched and single-world tests.

  The single-world test starts from one of them instead of compiling an
  unbatched reset: what it checks is the unbatched step.
  """
  keys = jax.random.split(jax.random.key(3), 3)
  return jax.jit(jax.vmap(env.reset))(keys)


def _step_then_restart(env):
  """What the fused step replaces, for one world: `Environment.step` with
  `share_reset_forward=False`."""
  transitions = env._transitions  # pylint: disable=protected-access

  def same_step(state, action):
    stepped = transitions.step(state, action)
    return control_flow.select_reset(
        stepped.last(), transitions.restart, (stepped,), stepped
    )

  def next_step(state, action):
    reset_key, step_key = keys_lib.next_step_keys(state.key)
    stepped = transitions.step(state.replace(key=step_key), action)
    return control_flow.select_reset(
        state.last(), transitions.reset, (reset_key, state), stepped
    )

  return same_step if env.auto_reset == 'same_step' else next_step


def test_the_fused_path_is_taken(env, monkeypatch):
  assert env._transitions.can_fuse_restart()  # pylint: disable=protected-access
  calls = []
  loop = control_flow.loop_with_reset
  monkeypatch.setattr(
      control_flow,
      'loop_with_reset',
      lambda *args, **kwargs: calls.append(1) or loop(*args, **kwargs),
  )
  jax.eval_shape(
      env.step, jax.eval_shape(env.reset, jax.random.key(0)), jnp.zeros(1)
  )
  assert calls
  # share_reset_forward=False asks for the separate reset.
  calls.clear()
  separate = _swing(auto_reset=env.auto_reset, share_reset_forward=False)
  jax.eval_shape(
      separate.step,
      jax.eval_shape(separate.reset, jax.random.key(0)),
      jnp.zeros(1),
  )
  assert not calls


def test_fused_step_equals_step_then_restart(env, reset_states):
  # The sub-steps carry the position stage: the restart's takes an
  # iteration of its own before its forward pass.
  assert env.carried_stage == 'position'
  _assert_fused_equals_step_then_restart(env, reset_states)


def test_fused_step_without_a_carried_stage_equals_step_then_restart():
  env = _swing(carry_stage='never')
  assert env.carried_stage is None
  keys = jax.random.split(jax.random.key(3), 3)
  _assert_fused_equals_step_then_restart(
      env, jax.jit(jax.vmap(env.reset))(keys)
  )


def _assert_fused_equals_step_then_restart(env, reset_states):
  reference = jax.jit(jax.vmap(_step_then_restart(env)))
  fused = jax.jit(jax.vmap(env.step))
  actions = jax.random.uniform(
      jax.random.key(4), (8, 3, 1), minval=-1, maxval=1
  )
  a = b = reset_states
  reset_alone = False
  for t in range(8):
    a, b = fused(a, actions[t]), reference(b, actions[t])
    # Bit for bit: the same computations, in one loop instead of two.
    test_environment.assert_trees_equal(a, b)
    first = np.asarray(a.first() if env.auto_reset == 'next_step' else a.last())
    reset_alone |= bool(first.any() and not first.all())
  assert reset_alone  # some world reset while others went on
  sizes = np.asarray(a.model_fields['geom_size'])
  assert len({float(s) for s in sizes[:, -1, 0]}) > 1  # drawn per world


class _SubstepDampedSwing(_RandomizedSwing):
  """`_RandomizedSwing` whose `before_substep` hook writes a model field
  (the pendulum's damping, from its velocity): the fused loop carries that
  field through its sub-steps, and keeps the ball's size out."""

  def before_substep(self, physics, action, key):
    physics = super().before_substep(physics, action, key)
    damping = 0.05 + 0.5 * jnp.abs(physics.bind(self.pendulum.joint).qvel)
    return physics.bind(self.pendulum.joint).set(damping=damping)


def test_a_model_field_a_sub_step_hook_writes_is_carried_through_the_loop(
    env, monkeypatch
):
  damped = _swing(_SubstepDampedSwing(), auto_reset=env.auto_reset)
  loops = []
  loop = control_flow.loop_with_reset
  monkeypatch.setattr(
      control_flow,
      'loop_with_reset',
      lambda *args, **kwargs: loops.append(args) or loop(*args, **kwargs),
  )
  states = jax.jit(jax.vmap(damped.reset))(
      jax.random.split(jax.random.key(3), 3)
  )
  _assert_fused_equals_step_then_restart(damped, states)
  # The loop's carry holds the field the hook writes; its invariants, those
  # only the restart writes (the ball's size, and what the model compiler
  # derives from it).
  (carry, *_), fixed = loops[0][5], loops[0][6]
  assert set(carry.model_fields) == {'dof_damping'}
  assert 'geom_size' in fixed and 'dof_damping' not in fixed


def test_both_phases_end_with_one_copy_of_the_skipped_sensors(env, monkeypatch):
  # The sub-steps skip the sensors and carry the position stage; the reset
  # runs the full forward pass: the step's end and the restart's both
  # compute the sensors the loop skipped, with the one copy that runs after
  # each phase's iterations.
  env = _swing(auto_reset=env.auto_reset, reset_forward='full')
  assert env.sensors_once_per_step and env.carried_stage == 'position'
  assert env.reset_forward_stage == 'full'
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), 2)
  )

  def step():
    return jax.make_jaxpr(jax.vmap(env.step))(states, jnp.zeros((2, 1)))

  step()  # the environment's analyses trace the sensors too
  copies = []
  sensors_of = substep_sensors.sensors_of
  monkeypatch.setattr(
      substep_sensors,
      'sensors_of',
      lambda *args, **kwargs: copies.append(1) or sensors_of(*args, **kwargs),
  )
  step()
  # The restart's sensors are the reset's: the accelerometer's fused case of
  # `test_substep_sensors.test_sensors_once_per_step_make_the_same_episodes`.
  assert len(copies) == 1


def test_conditional_branches_equal_loops(env, reset_states):
  # On a CPU the fused loop's end of step and restart are conditionals;
  # asked for loops, as on a GPU, the step computes the same states.
  loops = _swing(auto_reset=env.auto_reset, branches='loop')
  assert (env.branches, loops.branches) == ('cond', 'loop')
  by_cond, by_loop = jax.jit(jax.vmap(env.step)), jax.jit(jax.vmap(loops.step))
  zeros = jnp.zeros((3, 1))
  conds = lambda step: str(jax.make_jaxpr(step)(reset_states, zeros)).count(
      'cond['
  )
  assert conds(by_loop) < conds(by_cond)
  a = b = reset_states
  restarts = 0
  for t in range(8):
    action = jnp.full((3, 1), np.sin(t))
    a, b = by_cond(a, action), by_loop(b, action)
    test_environment.assert_trees_equal(a, b)
    restarted = a.first() if env.auto_reset == 'next_step' else a.last()
    restarts += int(np.asarray(restarted).sum())
  assert restarts  # the restart ran


def test_fused_single_world_equals_step_then_restart(env, reset_states):
  reference = jax.jit(_step_then_restart(env))
  fused = jax.jit(env.step)
  a = b = jax.tree.map(lambda x: x[1], reset_states)
  resets = 0
  for t in range(7):
    action = jnp.full((1,), np.sin(t))
    a, b = fused(a, action), reference(b, action)
    # The state is bit-for-bit the composition's. The reward, computed
    # inside the fused loop's last iteration rather than after the loop,
    # is compiled into other fusions: it may round differently in the
    # last bits (2 ulps seen; 4 allowed).
    test_environment.assert_trees_equal(a.replace(reward=b.reward), b)
    np.testing.assert_array_max_ulp(a.reward, b.reward, maxulp=4)
    resets += bool(a.first() if env.auto_reset == 'next_step' else a.last())
  assert resets  # the reset iteration ran


def _flat_eqn_count(jaxpr):
  count = 0
  for eqn in jaxpr.eqns:
    count += 1
    for sub in jax.extend.core.jaxprs_in_params(eqn.params):
      count += _flat_eqn_count(sub)
  return count


@pytest.mark.parametrize('reset_forward', ['full', 'observed'])
def test_the_step_program_loses_one_copy_of_the_forward_pass(
    env, reset_forward
):
  # The separate step recomputes its end-of-step stage (as the fused loop
  # does), so that the difference is the restart's forward pass alone.
  env = _swing(
      auto_reset=env.auto_reset,
      reset_forward=reset_forward,
      carry_stage='never',
  )
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), 2)
  )
  actions = jnp.zeros((2, 1))
  size = lambda f, *args: _flat_eqn_count(jax.make_jaxpr(f)(*args).jaxpr)
  fused = size(jax.vmap(env.step), states, actions)
  reference = size(jax.vmap(_step_then_restart(env)), states, actions)
  model = env.initial_physics().model
  forward = size(mjx.forward, model, env.initial_physics().data)
  if reset_forward == 'full':
    # The separate restart's full forward pass is what the fusion saves.
    assert reference - fused > 0.8 * forward
  else:
    # The task observes a position: the separate restart runs kinematics
    # only, so neither program holds a second full forward pass.
    assert env.reset_forward_stage == 'position'
    assert abs(reference - fused) < 0.5 * forward


_ACTUATED = """
<mujoco>
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="a" pos="0 0 1">
      <joint name="j1" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
      <site name="s1" pos="0.3 0 0"/>
      <body pos="0.3 0 0">
        <joint name="j2" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <site name="s2" pos="0.3 0 0"/>
      </body>
    </body>
  </worldbody>
  <tendon><spatial name="t"><site site="s1"/><site site="s2"/></spatial></tendon>
  <actuator>
    <motor name="m1" joint="j1" gear="2"/>
    <position joint="j2" kp="30" kv="2"/>
    <general tendon="t" dyntype="filter" dynprm="0.05" gaintype="affine"
             gainprm="4 1 0.5" biastype="affine" biasprm="0.3 -2 -1"
             forcelimited="true" forcerange="-3 5"/>
  </actuator>
  <sensor>
    <actuatorfrc actuator="m1"/>
    <jointactuatorfrc joint="j2"/>
    <accelerometer site="s2"/>
  </sensor>
</mujoco>
"""


def test_masked_forward_is_forward_with_actuation_disabled():
  m = mujoco.MjModel.from_xml_string(_ACTUATED)
  model = mjx.put_model(m)
  data = mjx.make_data(model).replace(
      qpos=jnp.array([0.4, -0.7]),
      qvel=jnp.array([1.0, -2.0]),
      ctrl=jnp.array([0.5, 0.3, 0.8]),
      act=jnp.array([0.6]),
  )
  disabled = model.replace(
      opt=model.opt.replace(
          disableflags=model.opt.disableflags | mjx.DisableBit.ACTUATION
      )
  )
  forward = jax.jit(
      lambda masked: mjx.forward(
          fused_restart.actuation_masked(model, masked),
          data,
      )
  )
  want = jax.jit(mjx.forward)(disabled, data)
  got = forward(True)
  for name in ('qfrc_actuator', 'qacc', 'qfrc_constraint', 'sensordata'):
    np.testing.assert_allclose(
        getattr(got, name), getattr(want, name), atol=1e-5, err_msg=name
    )
  np.testing.assert_array_equal(got.qfrc_actuator, 0.0)
  np.testing.assert_array_equal(got.actuator_force, 0.0)
  # Unmasked, it is the ordinary forward pass, actuators and all.
  unmasked = forward(False)
  ordinary = jax.jit(mjx.forward)(model, data)
  np.testing.assert_array_equal(unmasked.qfrc_actuator, ordinary.qfrc_actuator)
  assert np.abs(np.asarray(ordinary.qfrc_actuator)).max() > 0.1
  # And on the host: MuJoCo's own forward pass with actuation disabled.
  d = mujoco.MjData(m)
  d.qpos[:], d.qvel[:], d.ctrl[:], d.act[:] = (
      [0.4, -0.7],
      [1.0, -2.0],
      [0.5, 0.3, 0.8],
      [0.6],
  )
  m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
  mujoco.mj_forward(m, d)
  np.testing.assert_allclose(got.qacc, d.qacc, rtol=1e-4, atol=1e-4)


class _FromXml(composer.Task):

  def __init__(self, xml):
    self._root = composer.ModelWrapperEntity(xml)

  @property
  def root_entity(self):
    return self._root

  def get_reward(self, physics):
    return jnp.zeros(())


@pytest.mark.parametrize(
    'xml, fuses',
    [
        (_ACTUATED, True),
        (_ACTUATED.replace('<option ', '<option integrator="RK4" '), False),
        (
            _ACTUATED.replace(
                '<general tendon="t"',
                '<muscle tendon="t" lengthrange="0.1 0.5"/><general tendon="t"',
            ),
            False,
        ),
        (
            _ACTUATED.replace(
                '<body name="a" pos="0 0 1">', '<body name="a" gravcomp="1">'
            ).replace(
                'axis="0 1 0" damping',
                'actuatorgravcomp="true" axis="0 1 0" damping',
            ),
            False,
        ),
    ],
    ids=['euler', 'rk4', 'muscle', 'actuator_gravcomp'],
)
def test_fusion_applies_only_where_it_is_exact(xml, fuses):
  env = composer.Environment(_FromXml(xml))
  assert env._transitions.can_fuse_restart() == fuses  # pylint: disable=protected-access


def _conditionals(jaxpr, enclosing=()):
  """Each `cond` of a jaxpr, with the name stacks of the loops around it."""
  found = []
  for eqn in jaxpr.eqns:
    if eqn.primitive.name == 'cond':
      found.append(enclosing)
    inner = enclosing
    if eqn.primitive.name == 'while':
      inner = enclosing + (str(eqn.source_info.name_stack),)
    for param in eqn.params.values():
      for sub in param if isinstance(param, (tuple, list)) else (param,):
        sub = getattr(sub, 'jaxpr', sub)
        if hasattr(sub, 'eqns'):
          found.extend(_conditionals(sub, inner))
  return found


def _reset_loop(loops):
  """Whether one of the loops is the auto-reset's (its body resets)."""
  return any('reset' in loop or 'restart' in loop for loop in loops)


@pytest.mark.parametrize(
    'task_name, auto_reset',
    [('reach', 'same_step'), ('reach', 'next_step'), ('walk', 'same_step')],
)
def test_the_separate_step_branches_only_inside_its_reset(
    task_name, auto_reset
):
  """On a GPU each conditional costs a host round trip and copies of the
  state every step (docs/performance.md): the batched step's only
  conditionals are inside the reset, which runs only at steps where some
  world's episode ends (`branches='loop'`, a GPU's default)."""
  # pylint: disable=g-import-not-at-top
  if task_name == 'reach':
    from mjx_composer.suite.tasks import reach

    task = reach.Reach()
  else:
    from mjx_composer.suite.tasks import walk

    task = walk.Walk()
  # pylint: enable=g-import-not-at-top
  env = composer.Environment(
      task,
      time_limit=1.0,
      options=composer.ExecutionOptions(
          auto_reset=auto_reset, share_reset_forward=False, branches='loop'
      ),
  )
  assert env.branches == 'loop'
  states = jax.eval_shape(
      jax.vmap(env.reset), jax.random.split(jax.random.key(0), 2)
  )
  actions = jnp.zeros((2,) + env.action_spec().shape)
  jaxpr = jax.make_jaxpr(jax.vmap(env.step))(states, actions).jaxpr
  conditionals = _conditionals(jaxpr)
  assert all(_reset_loop(loops) for loops in conditionals), conditionals
  # The reset loop is there, and the sub-step scan branches nowhere.
  assert 'while' in str(jaxpr)
  # Nor does it loop but where `mjx.step` does (the constraint solver): the
  # sensors of the last sub-step are computed after the scan, not in a loop
  # run at one sub-step of the scan.
  (scan,) = [e for e in jaxpr.eqns if e.primitive.name == 'scan']
  model = env._transitions.initial.model  # pylint: disable=protected-access
  raw = jax.make_jaxpr(jax.vmap(lambda d: mjx.step(model, d)))(
      jax.tree.map(lambda x: jnp.stack([x, x]), mjx.make_data(model))
  ).jaxpr
  assert (
      jaxprs.count(scan.params['jaxpr'].jaxpr, 'while')
      == (jaxprs.count(raw, 'while'))
      > 0
  )
