"""Host-side tools: a dm_env environment over a batch, and rendering."""
