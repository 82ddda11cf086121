"""Vibration-mode identification from a tip-accelerometer free decay.

Two views: FFT peaks of the free decay (``spectrum``, the paper's view) and a parametric
sum-of-damped-sinusoids fit with 1-sigma uncertainties (``decay_fit``); ``identify``
combines them. ``cramer_rao`` gives the lower bound to judge the fit against;
``csv_input`` reads a time/acceleration CSV.
"""

from harness.identification.api import IdentificationResult, identify, sample_rate_hz
from harness.identification.cramer_rao import (
    CramerRaoBound,
    DampedMode,
    ModeBound,
    cramer_rao_bound,
)
from harness.identification.csv_input import AccelRecord, read_accel_csv
from harness.identification.decay_fit import (
    DecayFit,
    DecimationPlan,
    IdentifiedMode,
    PencilResult,
    damped_sinusoid_sum,
    decimate_causal,
    design_decimation,
    fit_free_decay,
    matrix_pencil,
)
from harness.identification.spectrum import (
    SpectralPeak,
    Spectrum,
    amplitude_spectrum,
    find_spectral_peaks,
)

__all__ = [
    "AccelRecord",
    "CramerRaoBound",
    "DampedMode",
    "DecayFit",
    "DecimationPlan",
    "IdentificationResult",
    "IdentifiedMode",
    "ModeBound",
    "PencilResult",
    "SpectralPeak",
    "Spectrum",
    "amplitude_spectrum",
    "cramer_rao_bound",
    "damped_sinusoid_sum",
    "decimate_causal",
    "design_decimation",
    "find_spectral_peaks",
    "fit_free_decay",
    "identify",
    "matrix_pencil",
    "read_accel_csv",
    "sample_rate_hz",
]
