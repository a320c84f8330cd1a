"""How an `Environment` runs: its hooks, state, reset and step (no public API).

Everything here is traced into the jitted `reset` and `step` of one world:
composer's hook order (`hooks`), the per-world state (`state`), the key
schedule (`keys`), the reset and the control step (`transitions`), the
auto-reset fused into the sub-step loop (`fused_restart`), the episode's
rules (`episode`), the loops that run once or never under `vmap`
(`control_flow`), and the analyses that find, once, from shapes, the
cheapest program that computes what the task reads (`data_reads`,
`reset_forward`, `substep_sensors`, `dirty_forward`).
"""
