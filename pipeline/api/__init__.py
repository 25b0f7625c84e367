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

Everything else is importable from the subpackages.
"""

from tympani.pipeline.diagnosis.analysis import diagnose
from tympani.pipeline.diagnosis.config import DiagnosisConfig
from tympani.pipeline.extract.batch import extract_batch
from tympani.pipeline.extract.config import ExtractConfig, VisionSteps
from tympani.pipeline.extract.manifest import read_manifest
from tympani.pipeline.extract.video import extract_video
from tympani.pipeline.force.sync import SyncConfig, sync_manifest, sync_trial
from tympani.pipeline.model.bounds import BoundsConfig, fit_bounds
from tympani.pipeline.model.identify import fit_synced
from tympani.pipeline.run import RunConfig, run_pipeline
from tympani.vision.angles import MeasureConfig, measure_frame, prepare_measurement
from tympani.vision.geometry import DEFAULT_PHANTOM, Phantom
from tympani.vision.registration import RegistrationConfig, register

__all__ = [
    "DEFAULT_PHANTOM", "BoundsConfig", "DiagnosisConfig", "ExtractConfig", "MeasureConfig", "Phantom", "RegistrationConfig",
    "RunConfig", "SyncConfig", "VisionSteps", "diagnose", "extract_batch", "extract_video", "fit_bounds", "fit_synced",
    "measure_frame", "prepare_measurement", "read_manifest", "register", "run_pipeline", "sync_manifest",
    "sync_trial",
]
