"""Sensors on a CAN bus (python-can, any interface by name), decoded by a DBC file or a byte layout."""
