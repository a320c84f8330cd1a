"""Bundled tasks: reach and push (the arm), walk (humanoid), joystick (Go1),
and walk_terrain and joystick_terrain, walk and joystick on generated terrain.

`registry` builds them by name (`registry.make_environment('walk', ...)`)
and takes your own (`registry.register`).
"""
