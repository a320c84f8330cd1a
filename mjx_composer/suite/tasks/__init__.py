"""Bundled tasks: reach and push (the arm), walk (humanoid), joystick (Go1).

`registry` builds them by name (`registry.make_environment('walk', ...)`)
and takes your own (`registry.register`).
"""
