"""Bundled entities: arenas, robots and props built in code with MjSpec."""
