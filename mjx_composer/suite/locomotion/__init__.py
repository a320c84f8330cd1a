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
  what its last episode achieved.

Each part keeps its per-world values in the task's state or in persistent
entries, and the task calls its methods from its own hooks.
"""
