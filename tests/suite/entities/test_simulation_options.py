"""The solver caps of the arm's tasks (`simulation_options.SOLVER_CAPS`)."""

import copy

import mujoco
import numpy as np
import pytest

from mjx_composer import environment
from mjx_composer.suite.entities import simulation_options
from mjx_composer.suite.tasks import push
from mjx_composer.suite.tasks import reach

_TASKS = {'reach': reach.Reach, 'push': push.Push}


@pytest.fixture(scope='module', params=sorted(_TASKS))
def model(request):
  return environment.Environment(_TASKS[request.param]()).mj_model


def test_tasks_write_the_caps_and_none_keeps_mujocos_defaults(model):
  caps = simulation_options.SOLVER_CAPS
  assert model.opt.iterations == caps['iterations']
  assert model.opt.ls_iterations == caps['ls_iterations']
  defaults = mujoco.MjModel.from_xml_string('<mujoco/>').opt
  uncapped = environment.Environment(
      reach.Reach(
          randomize=False, solver_iterations=None, solver_ls_iterations=None
      )
  ).mj_model
  assert uncapped.opt.iterations == defaults.iterations == 100
  assert uncapped.opt.ls_iterations == defaults.ls_iterations == 50


def _rollout(model, qpos, actions, substeps=5):
  data = mujoco.MjData(model)
  data.qpos[:] = qpos
  iterations = []
  trajectory = []
  for action in actions:
    data.ctrl[:] = action
    for _ in range(substeps):
      mujoco.mj_step(model, data)
      iterations.append(int(data.solver_niter[0]))
    trajectory.append(np.concatenate([data.qpos, data.qvel]))
  return np.array(trajectory), np.array(iterations)


def test_the_caps_barely_move_mujocos_trajectory(model):
  """MuJoCo's C solver needs a few iterations on these models.

  From random arm poses with every free body dropped from its built pose,
  under random actions for 2 s (contacts with the floor, the walls and the
  other bodies), the capped model's trajectory stays within 1e-4 of the
  uncapped one's in qpos and 5e-3 in qvel (measured, MuJoCo 3.17: 3e-5 and
  1.5e-3, a box's velocity in push; the arm's 8e-6 and 1e-4).
  """
  rng = np.random.default_rng(0)
  uncapped = copy.copy(model)
  uncapped.opt.iterations, uncapped.opt.ls_iterations = 100, 50
  arm = [
      j
      for j in range(model.njnt)
      if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
  ]
  differences = []
  for _ in range(3):
    qpos = model.qpos0.copy()
    low, high = model.jnt_range[arm].T
    qpos[model.jnt_qposadr[arm]] = rng.uniform(low, high)
    actions = rng.uniform(-1.0, 1.0, (100, model.nu))
    capped, iterations = _rollout(model, qpos, actions)
    reference, _ = _rollout(uncapped, qpos, actions)
    assert iterations.max() <= model.opt.iterations
    nq = model.nq
    np.testing.assert_allclose(capped[:, :nq], reference[:, :nq], atol=1e-4)
    np.testing.assert_allclose(capped[:, nq:], reference[:, nq:], atol=5e-3)
    differences.append(np.abs(reference - capped).max())
  assert max(differences) > 0  # the caps bind at times
