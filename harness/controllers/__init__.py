"""harness/controllers."""
