"""janome."""
