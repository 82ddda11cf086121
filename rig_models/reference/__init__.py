"""rig_models/reference."""
