"""The content: robots, props, arenas, tasks and the locomotion kit.

Parts built with composer's authoring API (`mjx_composer.Entity`, `Task`,
observables, variations), as a user's own parts are, and nothing more:
the framework does not import them, and they reach nothing of it a user's
code could not.

* `entities`: robots (the Go1, the humanoid, arms and hands), props,
  arenas, dm_control's walkers, arenas and props wrapped, and the vendored
  models they load (`entities/assets/`).
* `locomotion`: the locomotion kit: velocity commands, actuation delay,
  height scan, pushes, the policy's and critic's observations, the terrain
  arenas and their curriculum (`locomotion/terrain/`).
* `tasks`: reach, push, walk, walk_terrain, joystick, joystick_terrain, and
  `tasks.registry`, which builds them (and yours) by name.

Their old paths (`mjx_composer.entities`, `.tasks`, `.locomotion`) still
import for this release, with a `DeprecationWarning` (`old_paths`).
"""
