"""Bundled entities: arenas, props and robots, built in code with MjSpec or
loaded from the vendored models in `assets/` (see each folder's NOTICE)."""
