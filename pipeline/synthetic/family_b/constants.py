"""Constants of family B: effect names, units, quadrature sizes and the array's geometry."""

from __future__ import annotations

__all__ = ["EFFECTS", "G_N", "N_ARC", "N_WET", "ARRAY_LENGTH_MM", "ARRAY_D_TIP_MM", "ARRAY_D_BASE_MM"]


#: Names of the hidden effects (the diagnosis' names, docs/diagnosis.md).
EFFECTS: tuple[str, ...] = (
    "hydrodynamic_lift",
    "viscous_drag",
    "capstan",
    "sensor_lag",
    "sensor_drift",
    "pressure_profile",
)

#: Newtons per gram-force.
G_N: float = 9.80665e-3

#: Number of elements the contact arc is split into.
N_ARC: int = 64
#: Number of elements the wetted array is split into (viscous drag).
N_WET: int = 48
#: Array geometry (the default array): length and tip/base diameters, mm.
ARRAY_LENGTH_MM: float = 26.0
ARRAY_D_TIP_MM: float = 0.6
ARRAY_D_BASE_MM: float = 1.2
