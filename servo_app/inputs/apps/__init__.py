"""Pure building blocks of the input-driven applications: hand guiding, stand-off, target tracking."""
