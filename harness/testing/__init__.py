"""The verdict layer and suites (``harness test``); see branch ``verdict`` for judging."""
