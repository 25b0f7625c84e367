"""The sim-to-real gap: where the paper's model misses, which unmodelled effect explains it, how much
it shrinks once added, experiments that would decide ambiguous cases, the blind evaluation, and
the files of a diagnosis."""
