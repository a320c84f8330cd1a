"""The locomotion kit: parts any locomotion task composes.

* `commands.VelocityCommand`: per-world velocity commands, resampled every k
  steps, with heading control and standing worlds.
* `actuation_delay.ActuationDelay`: a per-world, per-episode delay of the
  actuation, in physics sub-steps.
* `height_scan.HeightScan`: an observable casting a grid of vertical rays
  from an entity's frame against the terrain.
* `terrain.TerrainGenerator`: an arena of sub-terrains (slopes, waves,
  stairs, stepping stones, beams, ...) in a grid of difficulty levels x
  kinds, all in one height field, with spawn points per tile;
  `terrain.RoughTerrain`: a height field whose profile each world samples;
  `curriculum.TerrainCurriculum`: each world's level, moved up or down by
  what its last episode achieved; `terrain.terrain_part.TerrainPart`: the
  three together with a height scan, as the terrain tasks use them.
* `pushes.Pushes`: random horizontal velocity kicks every k control steps.
* `policy_critic`: the policy's noisy, late inputs with a history
  (`policy_observable`, `uniform_noise`) and the critic's clean, current
  twins (`clean_twin`, `split_policy_and_critic`).

Each part keeps its per-world values in the task's state or in persistent
entries, and the task calls its methods from its own hooks.
"""
