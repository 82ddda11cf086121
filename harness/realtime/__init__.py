"""The host's real-time floor and the facts that decide it (``harness rt-check``).

- ``host``: kernel preemption model, PREEMPT_RT, CPU frequency governor, isolated CPUs, SMT,
  virtualisation, RT throttling and the limits on SCHED_FIFO and locked memory, read from
  ``/proc`` and ``/sys`` under a root path (tests give a fake one).
- ``floor``: a bare loop at the rate with the same real-time measures and clock the harness
  uses, doing a fixed amount of busy work a tick: what the host alone allows.
- ``check``: a plain verdict (HOLDS / MARGINAL / CANNOT HOLD) and what to change.
"""

DEFAULT_WORK_S = 150e-6
"""The floor loop's busy work a tick (s): about what the harness's own tick takes at 500 Hz
(codecs, bus, drivers, controller; ``work_ms`` p50 of a real-time run is 0.1-0.2 ms). Kept
here, not in ``floor``, so ``harness rt-check --help`` imports no clock and no numpy."""
