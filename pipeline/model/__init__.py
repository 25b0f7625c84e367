"""The seed paper's friction model and what is fitted with it: the model (Eqs. 2–7), its scenarios and
tables, identification from a synced table, the Eq. (8)–(9) safety bounds, the unmodelled effects,
and the statistics the fits share."""
