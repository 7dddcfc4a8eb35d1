"""stepper stage."""
