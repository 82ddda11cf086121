"""harness/studies."""
