"""How an `Environment` runs: its hooks, state, reset and step (no public API).

Everything here is traced into the jitted `reset` and `step` of one world:
composer's hook order (`hooks`), the per-world state (`state`), the reset and
the control step (`transitions`), the episode's rules (`episode`), and the
analyses that find, once at trace time, the cheapest program that computes
what the task reads (`data_reads`, `reset_forward`, `substep_sensors`).
"""
