"""fanuc."""
