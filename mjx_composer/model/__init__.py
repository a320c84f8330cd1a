"""Facts about the compiled model, found on the host once, at build.

Element handles and names resolved to static indices (`element_index`), the
checks that no element is silently dropped by composition
(`composition_checks`) and that MJX can run the model (`model_checks`), and
the reference kinematics MuJoCo's C library computes at build (`kinematics`).
"""
