"""`PropPlacer`: places props at sampled poses that do not collide.

Batched counterpart of composer's `initializers.PropPlacer`. One call places
the props of one world; `jax.vmap` (through `Environment.reset`) places them
in every world at once.

How a world is placed:

* Props are placed in order. For each, up to `max_attempts_per_prop`
  candidate poses are drawn from `position` and `quaternion` (evaluated like
  composer's, with the prop's pose at call time as initial value and the
  previous candidate as current value) inside a `lax.while_loop`; the first
  collision-free candidate is kept. Under `vmap` a world that has found its
  pose stops changing while the others keep sampling, so every world gets
  composer's "first valid sample" semantics.
* A collision is what composer counts: a contact with `dist <= 0` between a
  geom of the prop and a geom of anything placed or fixed so far. Props later
  in the order and the geoms of `ignore_contacts_with_entities` are left out,
  as composer's contype/conaffinity trick leaves them out. Only the geom pairs
  that can involve the prop are collided, with MJX's own narrow-phase
  functions on MJX's own pair list (see `contacts`).
* Free props whose geoms move rigidly with their freejoint (every bundled
  prop) are placed by one `lax.scan` over consecutive such props: a
  candidate's geom poses follow from the pose directly, so an attempt costs
  a few narrow-phase tests and no kinematics pass, and the loop compiles
  once whatever the number of props. Other props (fixed ones, or with joints
  of their own) are placed one by one through `set_pose` and a kinematics
  pass; a fixed prop's pose is its attachment frame's model
  `body_pos`/`body_quat`, which become per-world fields.
* With `settle_physics`, the physics is stepped with every non-prop joint
  held still (its qpos and qvel restored after each step, composer's
  `JointStaticIsolator`) until the props' `max|qvel|` and `max|qacc|` are
  below tolerance after `min_settle_physics_time`, for at most
  `max_settle_physics_time`; each world stops on its own. `time` is restored.
  Up to `max_settle_physics_attempts` rounds of placing and settling run,
  each resampling from the props' current poses.

Failures never raise inside jit: a prop with no valid candidate (or, with
`raise_exception_on_settle_failure`, physics that did not settle) marks the
episode with `physics.fail_initialization()`. The `Environment` then reruns
the `initialize_episode` hooks with a fresh key, up to `max_reset_attempts`
times, and reports `metrics['init_failures']`/`metrics['init_failed']`;
composer would raise `EpisodeInitializationError`.

Stateful variations (e.g. `deterministic.Sequence` over positions) keep
their state per world across episodes, as composer's Python objects do, in
the physics' persistent entries.

Where things live: this module holds the `PropPlacer` (its arguments, the
static tables it resolves once per compiled model, its variation states,
the settling); `placement_search` the search of collision-free poses;
`placement_tables` the tables' layout; `contacts` the narrow phase.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from mujoco import mjx
import numpy as np

from mjx_composer import initializer
from mjx_composer.initializers import contacts
from mjx_composer.initializers import placement_search
from mjx_composer.initializers import placement_tables
from mjx_composer.model import element_index
from mjx_composer.platform import backend
from mjx_composer.variation import rotations
from mjx_composer.variation import structures

_SETTLE_QVEL_TOL = 1e-3
_SETTLE_QACC_TOL = 1e-2


class PropPlacer(initializer.Initializer):
  """Places props at poses sampled from variations, without collisions.

  Args:
    props: a sequence of attached entities (free or fixed), placed in order.
    position: a fixed position (3,) or a `Variation` producing one. Use
      `variation.deterministic.Sequence` for a fixed list of positions (its
      position persists per world across episodes).
    quaternion: a fixed unit quaternion (4,) or a `Variation` producing one.
    ignore_collisions: if True, take the first sample without checking.
    max_qvel_tol: settling succeeds when every prop joint's |qvel| is below.
    max_qacc_tol: ... and every prop joint's |qacc| is below this.
    max_attempts_per_prop: candidate poses per prop before the world's
      initialization is marked failed.
    settle_physics: if True, step the physics so the props come to rest.
    min_settle_physics_time: settle for longer than this (seconds).
    max_settle_physics_time: settle for at most this long (seconds).
    max_settle_physics_attempts: rounds of placing and settling.
    raise_exception_on_settle_failure: if True, physics that did not settle
      marks the initialization failed (composer raised); otherwise the
      unsettled state is kept (composer logged a warning).

  Raises:
    ValueError: if `max_settle_physics_attempts` or `max_attempts_per_prop`
      is smaller than 1, `props` is empty, or a fixed `position` or
      `quaternion` does not broadcast to (3,) or (4,) (a variation drawing
      one of another shape is refused when the reset is traced).
  """

  def __init__(
      self,
      props,
      position,
      quaternion=rotations.IDENTITY_QUATERNION,
      ignore_collisions=False,
      max_qvel_tol=_SETTLE_QVEL_TOL,
      max_qacc_tol=_SETTLE_QACC_TOL,
      max_attempts_per_prop=20,
      settle_physics=False,
      min_settle_physics_time=0.0,
      max_settle_physics_time=2.0,
      max_settle_physics_attempts=1,
      raise_exception_on_settle_failure=False,
  ):
    if max_settle_physics_attempts < 1:
      raise ValueError(
          'max_settle_physics_attempts should be greater than '
          'zero to have any effect, but is '
          f'{max_settle_physics_attempts}'
      )
    if max_attempts_per_prop < 1:
      raise ValueError(
          'max_attempts_per_prop should be at least 1, but is '
          f'{max_attempts_per_prop}'
      )
    self._props = tuple(props)
    if not self._props:
      raise ValueError('PropPlacer needs at least one prop.')
    placement_search.check_pose_shape('position', position, None)
    placement_search.check_pose_shape('quaternion', quaternion, None)
    self._position = position
    self._quaternion = quaternion
    self._ignore_collisions = bool(ignore_collisions)
    self._max_qvel_tol = float(max_qvel_tol)
    self._max_qacc_tol = float(max_qacc_tol)
    self._max_attempts_per_prop = int(max_attempts_per_prop)
    self._settle_physics = bool(settle_physics)
    self._min_settle_physics_time = float(min_settle_physics_time)
    self._max_settle_physics_time = float(max_settle_physics_time)
    self._max_settle_physics_attempts = int(max_settle_physics_attempts)
    self._raise_exception_on_settle_failure = bool(
        raise_exception_on_settle_failure
    )
    self._tables: dict = {}
    self._search = placement_search.PoseSearch(
        self._props,
        position,
        quaternion,
        self._ignore_collisions,
        self._max_attempts_per_prop,
    )

  @property
  def props(self):
    return self._props

  @property
  def persistent_name(self) -> str:
    """The prefix of this placer's persistent entries (stateful variations).

    Derived from its props' full identifiers, so it does not depend on the
    order in which placers were built.
    """
    names = ','.join(p.full_identifier or p.name for p in self._props)
    return f'PropPlacer[{names}]'

  # -- static tables (host, at trace time) ----------------------------------

  def _resolve(
      self, index, ignore_contacts_with_entities
  ) -> placement_tables.Tables:
    """Resolves (and caches) everything static about this placement."""
    cache_key = (id(index), tuple(id(e) for e in ignore_contacts_with_entities))
    cached = self._tables.get(cache_key)
    if cached is not None and cached.index is index:
      return cached
    model = index.mj_model
    joint_kind = element_index.KINDS_BY_NAME['joint']
    body_kind = element_index.KINDS_BY_NAME['body']
    prop_geoms = [contacts.entity_geoms(index, prop) for prop in self._props]
    ignored = [
        contacts.entity_geoms(index, e) for e in ignore_contacts_with_entities
    ]
    fixed_fields, steps, run, all_prop_joints = (), [], [], []
    for i, prop in enumerate(self._props):
      if prop.attachment_frame is None:
        raise ValueError(
            f'PropPlacer: prop {prop.name!r} is not attached to '
            'the scene; attach it (e.g. with '
            'Arena.add_free_entity) before building the '
            'environment.'
        )
      own_joints = [
          index.element_id(joint_kind, j)
          for j in placement_tables.entity_elements(prop, 'joints')
      ]
      freejoint = prop.freejoint
      free_id = (
          None if freejoint is None else index.element_id(joint_kind, freejoint)
      )
      all_prop_joints.extend(
          own_joints + ([] if free_id is None else [free_id])
      )
      # Props later in the order are not placed yet: composer disables their
      # contacts, and those of the entities it was told to ignore.
      excluded = np.concatenate(
          [np.zeros(0, np.int32)] + prop_geoms[i + 1 :] + ignored
      )
      groups = (
          ()
          if self._ignore_collisions
          else contacts.pair_groups(model, prop_geoms[i], excluded)
      )
      chains = None
      if free_id is not None and not own_joints:
        frame = index.element_id(body_kind, prop.attachment_frame)
        chains = contacts.welded_chains(model, frame, prop_geoms[i])
      if chains is not None:
        run.append(
            (i, int(model.jnt_qposadr[free_id]), prop_geoms[i], chains, groups)
        )
        continue
      if run:
        steps.append(placement_tables.rigid_run(model, run))
        run = []
      if free_id is None:
        fixed_fields = ('body_pos', 'body_quat')
      steps.append(placement_tables.Single(i, groups))
    if run:
      steps.append(placement_tables.rigid_run(model, run))
    prop_qpos, prop_dofs = placement_tables.joint_addresses(
        model, all_prop_joints
    )
    held_qpos = np.setdiff1d(np.arange(model.nq), prop_qpos).astype(np.int32)
    held_dofs = np.setdiff1d(np.arange(model.nv), prop_dofs).astype(np.int32)
    tables = placement_tables.Tables(
        index, tuple(steps), held_qpos, held_dofs, prop_dofs, fixed_fields
    )
    self._tables[cache_key] = tables
    return tables

  def pair_groups(self, physics, prop_index, ignore_contacts_with_entities=()):
    """The geom pairs checked when placing prop `prop_index`.

    Returns `((MJX function key, (n, 2) geom ids), ...)`: the pairs whose
    contacts reject a candidate pose (useful to see what counts).
    """
    tables = self._resolve(physics.index, tuple(ignore_contacts_with_entities))
    for step in tables.steps:
      if (
          isinstance(step, placement_tables.Single)
          and step.prop_index == prop_index
      ):
        return step.pair_groups
      if (
          isinstance(step, placement_tables.RigidRun)
          and prop_index in step.prop_indices
      ):
        row = list(step.prop_indices).index(prop_index)
        return tuple(
            (key, pairs[row][valid[row]])
            for key, pairs, valid in zip(step.keys, step.pairs, step.valid)
            if valid[row].any()
        )
    raise IndexError(f'No prop {prop_index}.')

  # -- placement (device) ---------------------------------------------------

  def __call__(self, physics, key, ignore_contacts_with_entities=None):
    """Places the props of one world; returns the new Physics.

    Args:
      physics: the world's `Physics`.
      key: a JAX PRNG key.
      ignore_contacts_with_entities: entities whose contacts do not count
        (e.g. props another initializer will move afterwards).

    Returns:
      The Physics with the props placed and kinematics recomputed (positions
      and orientations are current; call `forward()` for the rest), marked
      with `fail_initialization` where placement (or, if requested,
      settling) failed.
    """
    ignore = tuple(ignore_contacts_with_entities or ())
    tables = self._resolve(physics.index, ignore)
    states = self._load_states(physics)
    if not self._settle_physics:
      physics, states, failed = self._place_props(physics, key, tables, states)
    else:
      physics, states, failed = self._place_and_settle(
          physics, key, tables, states
      )
    physics = self._store_states(physics, states)
    return physics.fail_initialization(failed).kinematics()

  def _load_states(self, physics):
    """Variation states: this world's persistent ones when it has them."""
    states = []
    for suffix, structure, size in (
        ('position', self._position, 3),
        ('quaternion', self._quaternion, 4),
    ):
      initial = structures.initial_state(structure, jnp.zeros(size))
      if initial is not None:
        initial = physics.get_persistent(
            f'{self.persistent_name}/{suffix}', initial
        )
      states.append(initial)
    return tuple(states)

  def _store_states(self, physics, states):
    for suffix, state in zip(('position', 'quaternion'), states):
      if state is not None:
        physics = physics.set_persistent(
            f'{self.persistent_name}/{suffix}', state
        )
    return physics

  def _place_props(self, physics, key, tables, states):
    """Places every prop in order; returns (physics, states, failed)."""
    return self._search.place_props(physics, key, tables, states)

  # -- settling (device) ----------------------------------------------------

  def _place_and_settle(self, physics, key, tables, states):
    """Rounds of placing then settling until one settles, per world."""
    if backend.of(physics.data).batch_shared_data:
      raise backend.WarpUnsupportedError(
          "PropPlacer(settle_physics=True) does not run on impl='warp' yet: "
          'its per-world settling loops carry the whole mjx.Data, which '
          "would copy MuJoCo Warp's contact buffer (shared by the batch) "
          "once per world. Use settle_physics=False or impl='jax'."
      )
    fields = tables.fixed_fields

    def unpack(carry):
      return carry[3].restore(physics.model, physics.index)

    def one_round(carry):
      n, _, placement_failed, _, states = carry
      current = unpack(carry)
      current, states, failed = self._place_props(
          current, jax.random.fold_in(key, n), tables, states
      )
      current, settled = self._settle(current, tables)
      return (
          n + 1,
          settled,
          jnp.logical_or(placement_failed, failed),
          current.carry(fields),
          states,
      )

    def unsettled(carry):
      n, settled, placement_failed, *_ = carry
      # composer raises as soon as a placement fails: no further rounds.
      return jnp.logical_and(
          jnp.logical_and(
              jnp.logical_not(settled), jnp.logical_not(placement_failed)
          ),
          n < self._max_settle_physics_attempts,
      )

    carry = (
        jnp.zeros((), jnp.int32),
        jnp.zeros((), bool),
        jnp.zeros((), bool),
        physics.carry(fields),
        states,
    )
    carry = jax.lax.while_loop(unsettled, one_round, carry)
    _, settled, failed, _, states = carry
    if self._raise_exception_on_settle_failure:
      failed = jnp.logical_or(failed, jnp.logical_not(settled))
    return unpack(carry), states, failed

  def _settle(self, physics, tables):
    """Steps with non-prop joints held; returns (physics, settled)."""
    model, start = physics.model, physics.data
    timestep = float(tables.index.mj_model.opt.timestep)
    max_steps = max(
        1, math.ceil(self._max_settle_physics_time / timestep - 1e-9)
    )
    held_qpos, held_dofs = tables.held_qpos, tables.held_dofs
    qpos_held, qvel_held = start.qpos[held_qpos], start.qvel[held_dofs]
    prop_dofs = tables.prop_dofs

    def step(carry):
      data, n, _ = carry
      data = mjx.step(model, data)
      # composer's JointStaticIsolator: only the props may move.
      data = data.replace(
          qpos=data.qpos.at[held_qpos].set(qpos_held),
          qvel=data.qvel.at[held_dofs].set(qvel_held),
      )
      n = n + 1
      if prop_dofs.size:
        qvel = jnp.max(jnp.abs(data.qvel[prop_dofs]))
        qacc = jnp.max(jnp.abs(data.qacc[prop_dofs]))
        still = jnp.logical_and(
            qvel < self._max_qvel_tol, qacc < self._max_qacc_tol
        )
      else:
        still = jnp.ones((), bool)
      # Elapsed time counted in steps: float32 `time` drifts.
      long_enough = n * timestep > self._min_settle_physics_time
      return data, n, jnp.logical_and(still, long_enough)

    def settling(carry):
      _, n, settled = carry
      return jnp.logical_and(jnp.logical_not(settled), n < max_steps)

    data, _, settled = jax.lax.while_loop(
        settling, step, (start, jnp.zeros((), jnp.int32), jnp.zeros((), bool))
    )
    return physics.replace(data=data.replace(time=start.time)), settled
