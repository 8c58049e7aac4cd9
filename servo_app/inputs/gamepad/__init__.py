"""Gamepads (Xbox, PlayStation, generic) through SDL2's GameController API: the pure mapping from a pad's
state to a twist and button actions (mapping), SDL's I/O (sdl, imported only when the adapter opens a
pad), and the adapter (adapter)."""
