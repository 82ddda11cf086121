"""Vibration-mode identification from a tip-accelerometer free decay.

Two views: FFT peaks of the free decay (``spectrum``, the paper's view) and a parametric
sum-of-damped-sinusoids fit with 1-sigma uncertainties (``decay_fit``); ``identify``
combines them on one free decay, ``identify_windows`` on several free-decay windows of one
record (a fast-decaying mode excited and left to ring down on its own, repeatedly, before
the slow modes' long free decay: repetitions combined, each mode reported from the windows
that determine it best; see ``windows``). ``cramer_rao`` gives the lower bound to judge
the fit against; ``csv_input`` reads a time/acceleration CSV.

Pure: arrays in, modes out (numpy and scipy). It imports no other package of the harness;
reading a run's recording and its free-decay windows is ``harness.core.identify``.
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
from harness.identification.windows import (
    AnalysisWindow,
    MultiWindowResult,
    WindowedMode,
    identify_window_segments,
    identify_windows,
)

__all__ = [
    "AccelRecord",
    "AnalysisWindow",
    "CramerRaoBound",
    "DampedMode",
    "DecayFit",
    "DecimationPlan",
    "IdentificationResult",
    "IdentifiedMode",
    "MultiWindowResult",
    "ModeBound",
    "PencilResult",
    "SpectralPeak",
    "Spectrum",
    "WindowedMode",
    "amplitude_spectrum",
    "cramer_rao_bound",
    "damped_sinusoid_sum",
    "decimate_causal",
    "design_decimation",
    "find_spectral_peaks",
    "fit_free_decay",
    "identify",
    "identify_window_segments",
    "identify_windows",
    "matrix_pencil",
    "read_accel_csv",
    "sample_rate_hz",
]
