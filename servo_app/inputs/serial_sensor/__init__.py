"""Sensors on a serial port: line-oriented ASCII and binary frames with checksums (pyserial)."""
