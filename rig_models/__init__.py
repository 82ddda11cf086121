"""rig_models."""
