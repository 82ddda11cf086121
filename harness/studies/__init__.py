"""harness/studies: each paper's study (a module defining ``register_study`` adds one to
``harness study``), and paper 003's frequency x amplitude sweep (``sweep``, run by
``harness sweep`` and the ``xu2018`` study; its workers come from ``harness.engine``)."""
