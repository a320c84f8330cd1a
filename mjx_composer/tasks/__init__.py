"""Bundled tasks: reach and push (the arm), walk (humanoid), joystick (Go1)."""
