"""Paper 003's (Xu 2018) published figures, for the comparison columns only: nothing of the
harness is computed from them."""

from __future__ import annotations

PAPER_003 = {
    "constrained_omega_rad_s": [2.11, 13.28, 37.15],
    "coupling_kg_m": [2.65, 0.54, 0.21],
    "hub_free_omega_rad_s": [2.8081, 13.643],
    "hub_free_measured_omega_rad_s": [2.7382, 13.9487],
}
"""The model: constrained frequencies (rad/s), coupling delta (kg m), hub-free frequencies
(rad/s) calculated and measured."""

PAPER_TABLE1 = {"measured_fft": [2.7382, 13.9487], "calculated": [2.8081, 13.643]}
"""Table 1: the identified modes (rad/s), measured (FFT) and calculated."""

PAPER_TABLE2 = {
    "case-a": {0.6: 0.020, 0.8: 0.025, 1.0: 0.041},
    "case-b": {0.6: 0.043, 0.8: 0.046, 1.0: 0.072},
    "case-c": {0.6: 0.018, 0.8: 0.023, 1.0: 0.037},
}
"""Table 2: the steady tip acceleration amplitude (m/s^2) of cases A/B/C by beta."""
