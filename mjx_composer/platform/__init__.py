"""What runs where: physics backends, devices and JAX's settings.

The MJX implementation that runs the physics and MuJoCo Warp's buffers
(`backend`), a batch of worlds over devices (`sharding`, `partitioner`), and
the JAX settings the package's entry points switch on (`compilation_cache`,
`prng_lowering`, `cpu_linalg`).
"""
