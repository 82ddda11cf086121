"""harness/shaping."""
