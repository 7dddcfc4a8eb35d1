"""gcode stage."""
