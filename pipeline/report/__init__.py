"""The report of a run (one HTML page) and the force-side figures."""
