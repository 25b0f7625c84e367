"""Tools for developers and for users checking tympani on their machine: the demo, the benchmarks and
the memory probe."""
