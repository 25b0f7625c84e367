"""Angles and forces to physics, in stages named after the data flow.

``extract``
    videos → per-frame angles (``tympani extract``)
``force``
    the lab's force and stage logs, and their synchronisation with the angles (``tympani sync``)
``model``
    the seed paper's friction model, its identification and the safety bounds (``fit``, ``bounds``)
``diagnosis``
    the sim-to-real gap: where, which effect, how much it shrinks (``tympani diagnose``)
``synthetic``
    rendered experiments and generated data with exact ground truth
``report``
    the HTML report and figures of a run
``run``
    all of the above on one manifest (``tympani run``)
``cli``, ``devtools``, ``io``
    the command line; demo and benchmarks; files that are never half written
"""
