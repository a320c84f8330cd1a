"""Robot arms and hands (dm_control's `entities.manipulators`)."""
