"""The sim-to-real gap: where the paper's model misses, which unmodelled effect explains it, how much
it shrinks once added, experiments that would decide ambiguous cases, the blind evaluation, and
the files of a diagnosis.

Modules, in the order a diagnosis runs: ``config`` (:class:`~tympani.pipeline.diagnosis.config.DiagnosisConfig`),
``prepare`` (the data), ``kernels`` and ``candidates`` (the models and their fits), ``evidence``
(lack of fit, where the gap lies, the bootstrap), ``identifiability``, ``decision`` (the verdict),
``experiments`` and ``analysis`` (:func:`~tympani.pipeline.diagnosis.analysis.diagnose`, which runs them, and
``diagnosis.json``); ``report`` writes the files, ``evaluation`` scores the diagnosis blind.
"""
