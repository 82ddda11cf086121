"""harness/identification."""
