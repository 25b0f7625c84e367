"""tympani: video and force analysis of robotic cochlear-implant electrode-array insertions.

This is the ``tympani`` package itself. Its two subpackages hold the work: ``tympani.vision``
(registration of the phantom and measurement of the array's angles in a frame) and
``tympani.pipeline`` (videos, force logs, the friction model, bounds and the sim-to-real
diagnosis). The names below are the main entry points, one per step of the data flow::

    import tympani

    tympani.extract_batch(tympani.read_manifest("manifest.csv"), "out/angles", tympani.ExtractConfig())
    synced = tympani.sync_manifest("manifest.csv", angles_dir="out/angles").table
    fit = tympani.fit_synced(synced)            # the paper's friction model, identified
    speeds, skipped = tympani.fit_bounds(synced)  # Eq. (8)-(9) force bounds per speed
    diagnosis = tympani.diagnose(synced)        # where the model misses, and why

Everything else is importable from the subpackages. The names load on first use, so that
``import tympani.pipeline.cli`` (the command line) does not pay for the whole package.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Each name of the API -> the module that defines it.
_HOME = {
    "diagnose": "tympani.pipeline.diagnosis.analysis",
    "DiagnosisConfig": "tympani.pipeline.diagnosis.config",
    "extract_batch": "tympani.pipeline.extract.batch",
    "ExtractConfig": "tympani.pipeline.extract.config",
    "VisionSteps": "tympani.pipeline.extract.config",
    "read_manifest": "tympani.pipeline.extract.manifest",
    "extract_video": "tympani.pipeline.extract.video",
    "SyncConfig": "tympani.pipeline.force.sync",
    "sync_manifest": "tympani.pipeline.force.sync",
    "sync_trial": "tympani.pipeline.force.sync",
    "BoundsConfig": "tympani.pipeline.model.bounds",
    "fit_bounds": "tympani.pipeline.model.bounds",
    "fit_synced": "tympani.pipeline.model.identify",
    "RunConfig": "tympani.pipeline.run",
    "run_pipeline": "tympani.pipeline.run",
    "MeasureConfig": "tympani.vision.angles",
    "measure_frame": "tympani.vision.angles",
    "prepare_measurement": "tympani.vision.angles",
    "DEFAULT_PHANTOM": "tympani.vision.geometry",
    "Phantom": "tympani.vision.geometry",
    "RegistrationConfig": "tympani.vision.registration",
    "register": "tympani.vision.registration",
}

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    """The API name ``name``, imported from its module on first use."""
    if name not in _HOME:
        raise AttributeError(f"module 'tympani' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOME[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))
