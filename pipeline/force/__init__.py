"""Force and stage logs as labs write them, and their synchronisation with the angles (the synced table)."""
