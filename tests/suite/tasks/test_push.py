"""The bundled push task: placement that never starts in collision, the zone,
reward and metrics, and its place in the demo command.

The placement is checked by running the task's `initialize_episode` on fresh
worlds (one jitted, vmapped call) rather than a full `reset`: compiling this
model's forward pass on a CPU takes minutes, and placement is what is new.
"""

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_composer as composer
from mjx_composer import cli
from mjx_composer.suite.tasks import push
from mjx_composer.suite.tasks import registry

_WORLDS = 256


def _fresh_physics(env):
  """One world's physics as `reset` starts it (model defaults, qpos0)."""
  return env.initial_physics()


@pytest.fixture(scope='module')
def pushed():
  task = push.Push()
  env = composer.Environment(task)
  physics = _fresh_physics(env)

  joints = list(task.arm.joints)

  @jax.jit
  def start(keys):
    def one(key):
      place_key, pose_key = jax.random.split(key)
      placed = task.initialize_episode(physics, place_key)
      # The reward is checked with the arm in a random pose too (the placer
      # leaves it at qpos0 in every world), inside the joint ranges.
      arm_qpos = jax.random.uniform(
          pose_key,
          (3,),
          minval=jnp.array([-np.pi, -1.6, -2.5]),
          maxval=jnp.array([np.pi, 1.6, 2.5]),
      )
      posed = placed.bind(joints).set(qpos=arm_qpos).kinematics()
      return (
          placed.data.qpos,
          placed.model.site_pos,
          placed.initialization_failed,
          task.get_metrics(placed),
          posed.data.qpos,
          task.get_reward(posed),
      )

    return jax.vmap(one)(keys)

  qpos, site_pos, failed, metrics, posed_qpos, reward = jax.tree.map(
      np.asarray, start(jax.random.split(jax.random.key(0), _WORLDS))
  )
  return (
      task,
      env,
      dict(
          qpos=qpos,
          site_pos=site_pos,
          failed=failed,
          metrics=metrics,
          posed_qpos=posed_qpos,
          reward=reward,
      ),
  )


def _box_positions(env, task, qpos):
  model = env.mj_model
  adrs = [
      model.jnt_qposadr[model.body(f'{b.name}/').jntadr[0]] for b in task.boxes
  ]
  return np.stack([qpos[:, a : a + 3] for a in adrs], axis=1)


def test_boxes_never_start_in_collision(pushed):
  task, env, out = pushed
  assert len(task.boxes) == 5
  assert not out['failed'].any()
  model = copy.deepcopy(env.mj_model)
  boxes = {model.geom(f'{b.name}/geom').id for b in task.boxes}
  for world in range(_WORLDS):  # every world, checked by MuJoCo
    model.site_pos[:] = out['site_pos'][world]
    data = mujoco.MjData(model)
    data.qpos[:] = out['qpos'][world]
    mujoco.mj_forward(model, data)
    bad = [
        (model.geom(c.geom1).name, model.geom(c.geom2).name, c.dist)
        for c in data.contact[: data.ncon]
        if ({c.geom1, c.geom2} & boxes) and c.dist < -1e-6
    ]
    assert not bad, (world, bad)
  positions = _box_positions(env, task, out['qpos'])
  assert np.all(np.abs(positions[..., :2]) < 0.5)
  # Clear of the arm's pedestal (radius 0.06) and spread over the floor.
  assert np.linalg.norm(positions[..., :2], axis=-1).min() > 0.06
  assert np.std(positions[..., 0]) > 0.2


def test_zone_moves_per_world_and_metrics_match(pushed):
  task, env, out = pushed
  mid = env.mj_model.site('zone/mid').id
  centres = out['site_pos'][:, mid, :2]
  radii = np.linalg.norm(centres, axis=-1)
  assert np.all((radii >= 0.25 - 1e-6) & (radii <= 0.4 + 1e-6))
  positions = _box_positions(env, task, out['qpos'])[..., :2]
  inside = np.all(np.abs(positions - centres[:, None]) < 0.1, axis=-1)
  np.testing.assert_array_equal(out['metrics']['boxes_in_zone'], inside.sum(-1))
  assert inside.any()
  np.testing.assert_allclose(
      out['metrics']['distance'],
      np.linalg.norm(positions - centres[:, None], axis=-1).mean(-1),
      rtol=1e-5,
  )


def _documented_reward(model, data, boxes, hand, lower, mid, upper):
  """Push's documented reward, from MuJoCo's C `mj_forward` of a state.

  A box is in the zone when its geom's xy position lies strictly inside
  (lower, upper) (composer's `PositionDetector`, 2D).
  """
  xpos = data.geom_xpos[boxes]
  in_zone = np.all(
      (model.site_pos[lower, :2] < xpos[:, :2])
      & (xpos[:, :2] < model.site_pos[upper, :2]),
      axis=-1,
  )
  closeness = 1 - np.tanh(
      np.linalg.norm(xpos[:, :2] - model.site_pos[mid, :2], axis=-1) / 0.3
  )
  to_hand = np.linalg.norm(xpos - data.site_xpos[hand], axis=-1)
  outside = to_hand[~in_zone]
  reach_term = 1 - np.tanh(outside.min() / 0.3) if outside.size else 1.0
  reward = 0.6 * in_zone.mean() + 0.3 * closeness.mean() + 0.1 * reach_term
  return reward, in_zone.sum(), reach_term


def test_reward_matches_the_documented_formula_on_mujocos_state(pushed):
  task, env, out = pushed
  model = copy.deepcopy(env.mj_model)
  boxes = [model.geom(f'{b.name}/geom').id for b in task.boxes]
  hand = model.site('arm/hand').id
  lower, mid, upper = (
      model.site(f'zone/{which}').id for which in ('lower', 'mid', 'upper')
  )
  terms = []
  for world in range(_WORLDS):
    model.site_pos[:] = out['site_pos'][world]
    data = mujoco.MjData(model)
    data.qpos[:] = out['posed_qpos'][world]
    mujoco.mj_forward(model, data)
    terms.append(
        _documented_reward(model, data, boxes, hand, lower, mid, upper)
    )
  expected, in_zone, reach_term = map(np.array, zip(*terms))
  # float32 kinematics and tanh against MuJoCo's float64: 4.3e-8 at most
  # (measured over these worlds); 5e-7 is four float32 steps at 1. A box
  # counted in the zone wrongly moves the reward by 0.12, a wrong distance
  # scale by 1e-2 or more.
  np.testing.assert_allclose(out['reward'], expected, rtol=0, atol=5e-7)
  # The worlds exercise every term: worlds with and without boxes in the
  # zone, the hand near a box and far from all.
  assert 0 < np.mean(in_zone > 0) < 1, in_zone
  assert reach_term.max() > 0.5 and reach_term.min() < 0.1, reach_term


def test_baseline_placements():
  fixed = push.Push(placement='fixed', num_boxes=3)
  env = composer.Environment(fixed)
  physics = _fresh_physics(env)
  placed = jax.jit(fixed.initialize_episode)(physics, jax.random.key(0))
  np.testing.assert_array_equal(placed.data.qpos, physics.data.qpos)
  # 'ring' turns the built ring per world: same radii, another angle.
  ring = push.Push(placement='ring', num_boxes=3)
  env = composer.Environment(ring)
  physics = _fresh_physics(env)
  qpos = jax.jit(
      jax.vmap(lambda k: ring.initialize_episode(physics, k).data.qpos)
  )(jax.random.split(jax.random.key(0), 4))
  positions = _box_positions(env, ring, np.asarray(qpos))
  np.testing.assert_allclose(
      np.linalg.norm(positions[..., :2], axis=-1), 0.3, atol=1e-5
  )
  assert np.std(positions[:, 0, 0]) > 0.05
  with pytest.raises(ValueError, match='`placement` must be one of'):
    push.Push(placement='random')


def test_demo_offers_the_push_task(capsys):
  assert 'push' in registry.names()
  env = registry.make_environment('push')
  spec = env.observation_spec()
  # Policy: 3 joint positions, 3 velocities, the hand, 5 boxes, the zone.
  assert spec['policy'].shape == (3 + 3 + 3 + 15 + 3,)
  # Critic: also 5 box velocities and 5 detection flags.
  assert spec['critic'].shape == (27 + 15 + 5,)
  assert env.action_spec().shape == (3,)
  # The choice is accepted (this stops at the argument check).
  with pytest.raises(SystemExit):
    cli.demo(['--task', 'push', '--worlds', '0'])
  assert 'must be positive' in capsys.readouterr().err
